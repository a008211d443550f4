"""`hec regress`: the whole pipeline (render, detect, ekf) on a small fixed scenario, against a baseline.

The baseline (experiments/regress/baseline.json, format ``hec-regression-baseline`` version 1) is
versioned with the code. It holds the scenario (the cell's settings, a fixed seed and ten camera views
of the board), the method, the thresholds, and the errors measured when it was set, per seed, with the
date, the command and the package versions. tests/test_regression.py runs trial 1 on every test run;
`hec regress --trials N` runs seeds seed, seed + 1, ..., seed + N - 1 and prints the comparison.

    hec regress [--trials N] [--baseline FILE] [--update] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands.verbs import HELP
from hec.regress.baseline_file import (
    DEFAULT_BASELINE,
    QUANTITIES,
    WAYPOINT_FILE,
    Baseline,
    BaselineError,
    Measurement,
    baseline_from_document,
    describe_update,
    environment,
    environment_changes,
    load_baseline,
    new_baseline_document,
    updated_document,
)

# The pipeline (sim, which picks the OpenGL backend, estimator, OpenCV) is imported where it is used, so
# that `hec` can import this module to build its parser on a machine without OpenGL.
if TYPE_CHECKING:
    from hec.estimator.geometry.waypoints import Waypoint
    from hec.sim.scenario import Scenario


# ---------------------------------------------------------------- the baseline file


# ---------------------------------------------------------------- the pipeline


def regression_waypoints(
    scenario: Scenario, views_deg: tuple[tuple[float, float, float], ...]
) -> list[Waypoint]:
    """Flange-pose waypoints (T_base_flange, metres) of the views, (tilt, azimuth, roll) degrees, from the
    scenario's board pose, mount and trajectory distance, as the rotation-rich trajectory makes them."""
    from hec.estimator.geometry.transforms import invert
    from hec.estimator.geometry.waypoints import Waypoint, look_at_board

    T_base_board = scenario.board.transform()
    T_cam_flange = invert(scenario.mount.transform())
    distance_m = scenario.trajectory.distance_m
    return [
        Waypoint(
            i,
            f"tilt {tilt:g} az {az:g} roll {roll:g}",
            T_base_flange=T_base_board @ look_at_board(tilt, az, roll, distance_m) @ T_cam_flange,
        )
        for i, (tilt, az, roll) in enumerate(views_deg)
    ]


def trial_scenario(baseline: Baseline, work_dir: Path) -> Scenario:
    """The baseline's scenario with its views written to work_dir/waypoints.csv."""
    from hec.estimator.geometry.waypoints import write_waypoint_file

    waypoint_file = (work_dir / WAYPOINT_FILE).resolve()
    write_waypoint_file(waypoint_file, regression_waypoints(baseline.scenario, baseline.views_deg))
    trajectory = baseline.scenario.trajectory.model_copy(update={"file": str(waypoint_file)})
    return baseline.scenario.model_copy(update={"trajectory": trajectory})


def run_trial(baseline: Baseline, scenario: Scenario, seed: int, dataset_dir: Path) -> Measurement:
    """Render the scenario with this seed into dataset_dir (must not exist), detect with the default
    settings (cached in the dataset), calibrate with the baseline's method, grade against the truth.
    Raises the pipeline's errors (pipeline_errors())."""
    from hec.estimator.geometry.transforms import pose_error
    from hec.estimator.io.dataset import load_dataset
    from hec.estimator.solve.calibration import MethodOptions
    from hec.estimator.solve.methods import run_method
    from hec.estimator.solve.problem import build_problem, dataset_robot_noise
    from hec.estimator.targets.qr import DetectorSettings
    from hec.sim.simulate import simulate
    from hec.support.detection import detect_and_cache

    result = simulate(scenario, dataset_dir, seed, progress=False)
    dataset = load_dataset(result.out_dir)
    observations, _, _ = detect_and_cache(dataset, DetectorSettings(), quiet=True)
    problem = build_problem(
        observations, dataset.board, dataset.intrinsics, dataset_robot_noise(dataset), use_depth=True
    )
    calibration = run_method(baseline.method, problem, MethodOptions(), observations)
    dt_m, dr_rad = pose_error(calibration.T_flange_cam, dataset.ground_truth.T_flange_cam)
    return Measurement(seed, 1e3 * dt_m, float(np.degrees(dr_rad)), result.frames)


def pipeline_errors() -> tuple[type[Exception], ...]:
    """The errors by which the pipeline says it could not produce a result from its input."""
    from hec.estimator.observe.frames import DatasetError
    from hec.estimator.observe.observations import ObservationCacheError
    from hec.estimator.solve.problem import CalibrationInputError
    from hec.sim.simulate import SimulationError

    return (SimulationError, CalibrationInputError, DatasetError, ObservationCacheError)


def measure(baseline: Baseline, scenario: Scenario, seed: int, work_dir: Path) -> Measurement:
    """run_trial into work_dir/seed-NNNN/; a pipeline error becomes a Measurement with its failure."""
    try:
        return run_trial(baseline, scenario, seed, work_dir / f"seed-{seed:04d}")
    except pipeline_errors() as exc:
        return Measurement(seed, failure=f"{type(exc).__name__}: {exc}")


# ---------------------------------------------------------------- the comparison


@dataclass(frozen=True)
class Check:
    """One quantity of one trial against its bound (the quantity's unit)."""

    quantity: str
    measured: float
    recorded: float | None
    bound: float
    kind: str  # 'absolute' or 'relative'

    @property
    def passed(self) -> bool:
        return math.isfinite(self.measured) and self.measured <= self.bound


@dataclass(frozen=True)
class TrialResult:
    """A trial's measurement and its checks (translation, rotation)."""

    measurement: Measurement
    checks: tuple[Check, ...]

    @property
    def passed(self) -> bool:
        return self.measurement.failure is None and all(c.passed for c in self.checks)


def compare(measurement: Measurement, baseline: Baseline) -> TrialResult:
    """The measurement against the baseline's rule (module docstring): the same call for the test and
    for `hec regress`."""
    recorded = baseline.recorded.get(measurement.seed)
    checks = []
    for quantity, _ in QUANTITIES:
        old = None if recorded is None else getattr(recorded, quantity)
        bound, kind = baseline.thresholds[quantity].bound(old)
        checks.append(Check(quantity, getattr(measurement, quantity), old, bound, kind))
    return TrialResult(measurement, tuple(checks))


def explain(result: TrialResult, baseline: Baseline) -> list[str]:
    """One sentence per failed check of a trial: what, how much, which bound and where it comes from."""
    m = result.measurement
    if m.failure is not None:
        return [f"seed {m.seed}: the pipeline failed: {m.failure}"]
    lines = []
    for (quantity, unit), check in zip(QUANTITIES, result.checks, strict=True):
        if check.passed:
            continue
        t = baseline.thresholds[quantity]
        origin = (
            f"{t.factor:g} x recorded {check.recorded:.4g} + {t.floor:g}"
            if check.kind == "relative"
            else "the absolute bound"
        )
        lines.append(
            f"seed {m.seed}: {quantity.split('_')[0]} error {check.measured:.4g} {unit} > "
            f"bound {check.bound:.4g} {unit} ({origin})"
        )
    return lines


def _cell(check: Check) -> str:
    recorded = f"{'-':>9}" if check.recorded is None else f"{check.recorded:9.5f}"
    mark = "r" if check.kind == "relative" else "a"
    return f"{check.measured:9.5f} {recorded} {check.bound:8.4f}{mark}"


TABLE_HEADER = (
    f"{'trial':>5} {'seed':>5} {'frames':>6} | {'err mm':>9} {'recorded':>9} {'bound':>9} | "
    f"{'err deg':>9} {'recorded':>9} {'bound':>9} | result"
)


def format_row(index: int, result: TrialResult, views: int) -> str:
    """A table row: errors, recorded figures ('-' if none), bounds (a: absolute, r: relative), verdict."""
    m = result.measurement
    head = f"{index:5d} {m.seed:5d} {m.frames:3d}/{views:<2d} |"
    if m.failure is not None:
        return f"{head} FAIL: {m.failure}"
    t, r = result.checks
    return f"{head} {_cell(t)} | {_cell(r)} | {'PASS' if result.passed else 'FAIL'}"


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


def format_summary(results: list[TrialResult]) -> list[str]:
    """RMS errors over the trials, and over the recorded seeds beside the recorded RMS."""
    done = [r for r in results if r.measurement.failure is None]
    lines = []
    if len(done) > 1:
        t = _rms([r.measurement.translation_mm for r in done])
        d = _rms([r.measurement.rotation_deg for r in done])
        lines.append(f"RMS over {len(done)} trials: {t:.4f} mm, {d:.5f} deg")
    paired = [r for r in done if r.checks[0].recorded is not None]
    if len(paired) > 1:
        now = [
            _rms([getattr(r.checks[i], a) for r in paired]) for i in (0, 1) for a in ("measured", "recorded")
        ]
        lines.append(
            f"RMS over the {len(paired)} recorded seeds: {now[0]:.4f} mm (recorded {now[1]:.4f}), "
            f"{now[2]:.5f} deg (recorded {now[3]:.5f})"
        )
    return lines


# ---------------------------------------------------------------- --update


# ---------------------------------------------------------------- the command


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the `regress` subcommand to the `hec` parser."""
    p = sub.add_parser("regress", help=HELP["regress"])
    p.add_argument(
        "--trials",
        type=_positive,
        default=1,
        metavar="N",
        help="seeds seed .. seed+N-1 (default: %(default)s)",
    )
    p.add_argument(
        "--baseline",
        type=Path,
        default=DEFAULT_BASELINE,
        metavar="FILE",
        help="baseline JSON (default: experiments/regress/baseline.json)",
    )
    p.add_argument(
        "--update",
        action="store_true",
        help="record these trials' errors as the new figures (refused if a trial breaks the absolute bound); "
        "a missing FILE is created with the built-in scenario",
    )
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep the datasets in DIR (new or empty folder)")


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def _command(args: argparse.Namespace) -> str:
    words = ["hec", "regress", "--trials", str(args.trials)]
    if args.baseline != DEFAULT_BASELINE:
        words += ["--baseline", str(args.baseline)]
    return " ".join([*words, "--update"])


def _work_dir(keep: Path | None) -> tuple[Path, tempfile.TemporaryDirectory | None]:
    """Where the datasets go: keep (created; must be new or empty) or a temporary folder."""
    if keep is None:
        tmp = tempfile.TemporaryDirectory(prefix="hec-regress-")
        return Path(tmp.name), tmp
    if keep.exists() and (not keep.is_dir() or any(keep.iterdir())):
        raise FileExistsError(f"{keep}: --keep needs a new or empty folder (nothing in it is replaced)")
    keep.mkdir(parents=True, exist_ok=True)
    return keep, None


def _load_for(args: argparse.Namespace) -> Baseline:
    """The baseline; with --update and a missing file, a new one from the built-in scenario."""
    if args.update and not args.baseline.exists():
        from hec.calibration.report import check_json_path

        check_json_path(args.baseline)
        print(f"{args.baseline} does not exist: a new baseline from the built-in scenario will be written")
        return baseline_from_document(new_baseline_document(), args.baseline, require_record=False)
    return load_baseline(args.baseline)


def _print_header(baseline: Baseline) -> None:
    recorded = baseline.document.get("recorded", {})
    print(f"baseline: {baseline.path}")
    if recorded.get("set_at"):
        print(f"  set {recorded['set_at']} by `{recorded.get('command', '?')}`")
    changes = environment_changes(recorded.get("environment", {}), environment())
    if changes:
        print(f"  environment differs from the recorded one: {'; '.join(changes)}")
    print(
        f"scenario: {len(baseline.views_deg)} views, method {baseline.method}; bound (mm, deg) = "
        "min(absolute, factor x recorded + floor), a: absolute, r: relative"
    )
    for quantity, t in baseline.thresholds.items():
        print(f"  {quantity}: absolute {t.absolute:g}, factor {t.factor:g}, floor {t.floor:g}")
    print(TABLE_HEADER)


def regress(baseline: Baseline, trials: int, work_dir: Path) -> list[TrialResult]:
    """Run and print the trials (seeds baseline.seed + 0 .. trials - 1), each row as it finishes."""
    _print_header(baseline)
    scenario = trial_scenario(baseline, work_dir)
    results = []
    for i in range(trials):
        result = compare(measure(baseline, scenario, baseline.seed + i, work_dir), baseline)
        results.append(result)
        print(format_row(i + 1, result, len(baseline.views_deg)), flush=True)
    for line in format_summary(results):
        print(line)
    return results


def _update(baseline: Baseline, results: list[TrialResult], command: str) -> int:
    """Write the new figures unless a trial failed outright or broke the absolute bound."""
    unrecorded = replace(baseline, recorded={})
    broken = [line for r in results for line in explain(compare(r.measurement, unrecorded), baseline)]
    if broken:
        print(f"not updating {baseline.path}: a trial failed or broke the absolute bound:", file=sys.stderr)
        for line in broken:
            print(f"  {line}", file=sys.stderr)
        return 1
    from hec.calibration.report import write_json

    measurements = [r.measurement for r in results]
    write_json(baseline.path, updated_document(baseline.document, measurements, command))
    print(f"updated {baseline.path}:")
    for line in describe_update(baseline.recorded, measurements):
        print(f"  {line}")
    return 0


def run(args: argparse.Namespace) -> int:
    """`hec regress`: 0 when every trial passes (or --update wrote the file), 1 on a regression, 2 on
    bad input (the baseline file, --keep)."""
    try:
        baseline = _load_for(args)
        work_dir, tmp = _work_dir(args.keep)
    except (BaselineError, FileExistsError, FileNotFoundError, IsADirectoryError) as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    try:
        results = regress(baseline, args.trials, work_dir)
    finally:
        if tmp is not None:
            tmp.cleanup()
    if args.keep is not None:
        print(f"datasets: {args.keep}/seed-NNNN/")
    if args.update:
        return _update(baseline, results, _command(args))
    failures = [line for r in results for line in explain(r, baseline)]
    for line in failures:
        print(f"FAIL {line}")
    if failures:
        print(
            "a regression, or an intended change: check with more --trials, then record it with --update",
            file=sys.stderr,
        )
        return 1
    print(f"PASS: {len(results)} trial(s) within the bounds of {baseline.path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m hec.commands.regress ...`, the same as `hec regress ...`."""
    parser = argparse.ArgumentParser(prog="hec")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    return run(parser.parse_args(["regress", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    sys.exit(main())

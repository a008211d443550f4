"""A sweep's rows as the report reads them (typed and checked against the row contract) and
their statistics per grid cell and method, plus one filter's convergence on a representative trial."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hec.estimator.geometry.lie import pose_minus
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.problem import CalibrationProblem
from hec.sweep.rows import FLOAT_COLUMNS, ID_COLUMNS, OPTIONAL_COLUMNS, RESULT_COLUMNS, ROWS_FILE

# Columns every row has (hec.sweep.runner's row contract; seed is text, e.g. "seed/cell/trial"). Every
# other column is a parameter of the trial (pixel_sigma_px, waypoints, trajectory, mount, ...): swept
# when it takes more than one value over the rows, fixed otherwise.
STRING_COLUMNS = (*ID_COLUMNS, *RESULT_COLUMNS[:3])
ROW_COLUMNS = (*STRING_COLUMNS, *FLOAT_COLUMNS)


STATUSES = ("ok", "failed")
FIDELITIES = ("measurements", "render")


class ReportError(ValueError):
    """The sweep folder has no rows, or a row is not what the row contract says."""


def load_report_rows(out_dir: Path) -> list[dict]:
    """The sweep's result rows of out_dir, one dict per trial x method, typed by column name.

    Strict, unlike hec.sweep.rows.load_rows (which skips what a resume rewrites): a row that
    does not read is an error naming the file, line and column. Reads DIR/rows.csv."""
    return read_rows_csv(Path(out_dir) / ROWS_FILE)


def read_rows_csv(path: Path) -> list[dict]:
    """Rows of a CSV file with a header: contract columns typed (FLOAT_COLUMNS float, empty = NaN;
    the others text), parameter columns int, float or text as they read (empty = None).
    Raises ReportError naming the file, line and column."""
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames
            raw = list(reader)
    except FileNotFoundError:
        raise ReportError(
            f"{path}: file missing; expected the result rows of `hec sweep CONFIG.toml --out {path.parent}`"
        ) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"{path}: not a readable CSV file ({exc})") from None
    if not header:
        raise ReportError(f"{path}: empty file; expected a header line and one row per trial x method")
    rows = []
    for line, values in enumerate(raw, start=2):
        if None in values:
            raise ReportError(f"{path}, line {line}: more values than the {len(header)} header columns")
        rows.append({name: _typed(value, name, f"{path}, line {line}") for name, value in values.items()})
    return rows


def _typed(text: str | None, column: str, where: str) -> object:
    text = "" if text is None else text.strip()
    if column in FLOAT_COLUMNS:
        try:
            return float(text) if text else math.nan
        except ValueError:
            raise ReportError(f"{where}, column {column!r}: expected a number, got {text!r}") from None
    if column in STRING_COLUMNS:
        return text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text or None


def check_rows(rows: list[dict], source: str) -> None:
    """Raise ReportError naming source unless there are rows with every ROW_COLUMNS column,
    known statuses and fidelities, and each cell has one value of each parameter."""
    if not rows:
        raise ReportError(f"{source}: no result rows; run `hec sweep` into this folder first")
    missing = [c for c in ROW_COLUMNS if c not in rows[0] and c not in OPTIONAL_COLUMNS]
    if missing:
        raise ReportError(
            f"{source}: missing column(s) {', '.join(missing)}; expected {', '.join(ROW_COLUMNS)}"
        )
    parameters = parameter_columns(rows)
    first_of_cell: dict[str, dict] = {}
    for i, row in enumerate(rows):
        for column, allowed in (("status", STATUSES), ("fidelity", FIDELITIES)):
            if row[column] not in allowed:
                raise ReportError(
                    f"{source}, data row {i + 1}: column {column!r} must be one of {', '.join(allowed)}, "
                    f"got {row[column]!r}"
                )
        first = first_of_cell.setdefault(row["cell"], row)
        for p in parameters:
            if not _same(row.get(p), first.get(p)):
                raise ReportError(
                    f"{source}, data row {i + 1}: cell {row['cell']!r} has two values of {p!r}: "
                    f"{first.get(p)!r} and {row.get(p)!r}"
                )


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _num(value: object) -> float:
    """A row value as a float; None and empty text are NaN."""
    if value is None or value == "":
        return math.nan
    return float(value)


def _ok_values(rows: list[dict], column: str, **match: object) -> np.ndarray:
    """The finite values of column in the ok rows whose fields equal match."""
    values = np.array(
        [
            _num(r[column])
            for r in rows
            if r["status"] == "ok" and all(_same(r.get(k), v) for k, v in match.items())
        ],
        dtype=float,
    )
    return values[np.isfinite(values)]


def parameter_columns(rows: list[dict]) -> list[str]:
    """The columns beyond the row contract (the trials' parameters), in column order."""
    return [c for c in _unique(c for r in rows for c in r) if c not in ROW_COLUMNS]


def swept_parameters(rows: list[dict]) -> list[str]:
    """The parameter columns taking more than one value over the rows, in column order."""
    return [p for p in parameter_columns(rows) if len(_unique(repr(r.get(p)) for r in rows)) > 1]


def fixed_parameters(rows: list[dict]) -> dict:
    """The parameter columns taking one value over the rows, with that value."""
    swept = swept_parameters(rows)
    return {p: rows[0].get(p) for p in parameter_columns(rows) if p not in swept}


def _unique(values: Iterable) -> list:
    return list(dict.fromkeys(values))


@dataclass
class Stats:
    """Median, 95th percentile (linear interpolation) and RMS of errors; the RMS Cramer-Rao bound
    over the same trials (those with a finite bound) and the ratio RMS / bound. NaN when empty."""

    median: float
    p95: float
    rms: float
    crb_rms: float
    ratio: float

    @classmethod
    def of(cls, errors: np.ndarray, crb: np.ndarray) -> Stats:
        """errors, crb: (N,) per ok trial; crb NaN where the mount was not observable."""
        if len(errors) == 0:
            return cls(*[math.nan] * 5)
        finite = np.isfinite(crb)
        rms_bounded = _rms(errors[finite])
        crb_rms = _rms(crb[finite])
        ratio = rms_bounded / crb_rms if finite.any() and crb_rms > 0 else math.nan
        return cls(float(np.median(errors)), float(np.percentile(errors, 95)), _rms(errors), crb_rms, ratio)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


@dataclass
class CellSummary:
    """One grid cell x method. trials: rows (ok and failed); ok: rows with status ok.
    crb_trials: ok trials with a finite bound (the ratio's trials). mean_nees: over ok trials with
    a covariance (6 on average when honest), NaN without. failures: distinct messages, counted."""

    cell: str
    method: str
    fidelity: str
    parameters: dict
    trials: int
    ok: int
    translation_mm: Stats
    rotation_deg: Stats
    crb_trials: int
    mean_nees: float
    median_time_s: float
    failures: dict[str, int] = field(default_factory=dict)

    @property
    def success_rate(self) -> float:
        return self.ok / self.trials


def summarise(rows: list[dict]) -> list[CellSummary]:
    """Per grid cell and method (in order of first appearance), the statistics of CellSummary."""
    parameters = swept_parameters(rows)
    out = []
    for cell in _unique(r["cell"] for r in rows):
        cell_rows = [r for r in rows if r["cell"] == cell]
        for method in _unique(r["method"] for r in cell_rows):
            mine = [r for r in cell_rows if r["method"] == method]
            ok = [r for r in mine if r["status"] == "ok"]

            def column(name: str, ok: list[dict] = ok) -> np.ndarray:
                return np.array([_num(r[name]) for r in ok], dtype=float)

            nees = column("nees")
            nees = nees[np.isfinite(nees)]
            failures: dict[str, int] = {}
            for r in mine:
                if r["status"] == "failed":
                    message = r["failure"] or "(no message)"
                    failures[message] = failures.get(message, 0) + 1
            out.append(
                CellSummary(
                    cell=cell,
                    method=method,
                    fidelity=mine[0]["fidelity"],
                    parameters={p: mine[0].get(p) for p in parameters},
                    trials=len(mine),
                    ok=len(ok),
                    translation_mm=Stats.of(column("error_translation_mm"), column("crb_translation_mm")),
                    rotation_deg=Stats.of(column("error_rotation_deg"), column("crb_rotation_deg")),
                    crb_trials=int(np.sum(np.isfinite(column("crb_translation_mm")))),
                    mean_nees=float(np.mean(nees)) if len(nees) else math.nan,
                    median_time_s=float(np.median(column("time_s"))) if ok else math.nan,
                    failures=failures,
                )
            )
    return out


@dataclass
class Convergence:
    """A filter over one trial. waypoints: (S,) waypoints taken in after each update (the last
    one + 1 for a prior fused after the frames). error: (S, 6) estimate minus truth in the
    hec.estimator.geometry.lie convention (m along the flange axes, rad about the camera axes). sigma: (S, 6)
    the filter's 1-sigma of the same components."""

    method: str
    waypoints: np.ndarray
    error: np.ndarray
    sigma: np.ndarray


def convergence(
    problem: CalibrationProblem, T_flange_cam_true: np.ndarray, options: MethodOptions, iterated: bool = False
) -> Convergence:
    """Run ekf (or iekf) over the problem's frames, as run_method would (with the learned noise when
    options.learn_noise, its levels' uncertainty added to every update), and keep each update's
    error and 1-sigma."""
    from hec.estimator.solve.filters import filter_steps
    from hec.estimator.solve.methods import learned_setup
    from hec.estimator.solve.noise_learning import learn_noise

    widening = np.zeros((6, 6))
    if options.learn_noise:
        name = "iekf" if iterated else "ekf"
        learned = learn_noise(problem, options)
        _, problem, options = learned_setup(name, problem, options, learned)
        # The levels' own uncertainty, as run_method adds it (hec.estimator.solve.level_uncertainty).
        widening = learned.level_widening if learned.level_widening is not None else widening
    position = {f.frame: i + 1 for i, f in enumerate(problem.frames)}
    waypoints, errors, sigmas = [], [], []
    for step in filter_steps(problem, options, iterated):
        waypoints.append(position[step.frame] if step.frame >= 0 else len(problem.frames) + 1)
        errors.append(pose_minus(step.state.T_flange_cam, T_flange_cam_true))
        sigmas.append(np.sqrt(np.diag(step.covariance)[:6] + np.diag(widening)))
    return Convergence("iekf" if iterated else "ekf", np.array(waypoints), np.array(errors), np.array(sigmas))


def representative_trial(seed: int) -> tuple[CalibrationProblem, np.ndarray]:
    """A measurement-level trial like the sweep's: a random mount, the default views, board and
    noise (hec.support.synthetic_scenes). Returns the problem and the true T_flange_cam (4, 4)."""
    from hec.estimator.observe.synthetic import SyntheticNoise
    from hec.estimator.solve.problem import build_problem
    from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene

    rng = np.random.default_rng(seed)
    noise = SyntheticNoise()
    T_flange_cam = random_mount(rng)
    observations = scene(T_flange_cam, rng, noise)
    return build_problem(observations, BOARD, INTRINSICS, noise.robot), T_flange_cam

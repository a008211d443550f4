"""Monte-Carlo of every estimator at measurement level against the Cramer-Rao bound, and run times.

Each trial draws a random mount (hec.support.synthetic_scenes.random_mount), the
default views and board, and synthetic observations with the default noise
(0.3 px corners, stereo depth noise, 0.1 mm / 0.01 degree robot pose noise). Three cases:

    robot noise          data and model with robot pose noise (all methods)
    no robot noise       exact flange poses in data and model
    robot noise ignored  data with robot pose noise, model taking the poses as exact

Per method: RMS translation / rotation error, its ratio to the bound (sqrt of the
mean trace of the CRB over trials), mean NEES against the 95 % chi-square band for
the mean of that many 6-dof values, failures. Then the time per method for 15
waypoints x 8 markers.

    .venv/bin/python -m hec.bench.estimators [--trials 200] [--seed 0] [--workers 2] [--plot F.png]
        [--page PATH.md]

--page also writes the printed tables as a documentation page (with the plot, PAGE's stem .png, beside it).
"""

from __future__ import annotations

import os

# One BLAS thread per process: the trials run in parallel processes, and small matrices
# gain nothing from threads (with both, OpenBLAS oversubscribes and stalls).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402
from tqdm import tqdm  # noqa: E402

from hec.calibration.report import check_json_path, write_json  # noqa: E402
from hec.estimator.common.noise import RobotPoseNoise  # noqa: E402
from hec.estimator.geometry.lie import pose_minus  # noqa: E402
from hec.estimator.observe.synthetic import SyntheticNoise  # noqa: E402
from hec.estimator.solve.baselines import JOINT_LINEAR_METHODS, OPENCV_METHODS  # noqa: E402
from hec.estimator.solve.calibration import MethodOptions  # noqa: E402
from hec.estimator.solve.measurement_model import HandEyeState  # noqa: E402
from hec.estimator.solve.methods import METHODS, run_method  # noqa: E402
from hec.estimator.solve.observability import observability  # noqa: E402
from hec.estimator.solve.problem import CalibrationInputError, build_problem  # noqa: E402
from hec.support.results_page import write_results_page  # noqa: E402
from hec.support.synthetic_scenes import BOARD, INTRINSICS, T_BASE_BOARD, random_mount, scene  # noqa: E402

EXACT_POSES = RobotPoseNoise(0.0, 0.0)
MODEL_METHODS = ("ekf", "iekf", "ukf", "batch")
CASES = {
    "robot noise": (SyntheticNoise(), None, tuple(METHODS)),
    "no robot noise": (replace(SyntheticNoise(), robot=EXACT_POSES), None, MODEL_METHODS),
    "robot noise ignored": (SyntheticNoise(), EXACT_POSES, ("ekf", "batch")),
}
TIMING_VIEWS = 15
# The default rendered trajectory's views, for time_against_park.
PARK_VIEWS = 17


def run_trial(case: str, seed: int, trial: int) -> dict:
    """One trial of one case: per method the error (6,) in the hec.estimator.geometry.lie convention, NEES,
    time, or the error message; and the CRB's diagonal (6,) at the truth."""
    noise, model_robot, methods = CASES[case]
    rng = np.random.default_rng([seed, trial])
    X = random_mount(rng)
    observations = scene(X, rng, noise=noise)
    truth_problem = build_problem(observations, BOARD, INTRINSICS, noise.robot)
    # The bound is that of the true noise; the methods see the model's (the same unless it ignores some).
    problem = (
        truth_problem if model_robot is None else build_problem(observations, BOARD, INTRINSICS, model_robot)
    )
    crb = observability(truth_problem, HandEyeState(X, T_base_board=T_BASE_BOARD)).crb_covariance
    out = {"crb": np.diag(crb), "methods": {}}
    for method in methods:
        try:
            result = run_method(method, problem, MethodOptions(), observations)
        except CalibrationInputError as exc:
            out["methods"][method] = {"failed": str(exc)}
            continue
        error = pose_minus(result.T_flange_cam, X)
        nees = None if result.covariance is None else float(error @ np.linalg.solve(result.covariance, error))
        out["methods"][method] = {"error": error, "nees": nees, "time_s": result.diagnostics["time_s"]}
    return out


def summarise(trials: list[dict]) -> dict:
    """Per method: RMS errors, ratios to the bound, mean NEES, failures, median time."""
    crb = np.array([t["crb"] for t in trials])
    bound_mm = 1e3 * np.sqrt(np.mean(crb[:, :3].sum(axis=1)))
    bound_deg = np.degrees(np.sqrt(np.mean(crb[:, 3:].sum(axis=1))))
    rows = {}
    for method in trials[0]["methods"]:
        runs = [t["methods"][method] for t in trials]
        ok = [r for r in runs if "error" in r]
        if not ok:
            rows[method] = {"failures": len(runs), "example": runs[0]["failed"]}
            continue
        E = np.array([r["error"] for r in ok])
        rms_mm = 1e3 * np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1)))
        rms_deg = np.degrees(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1))))
        nees = [r["nees"] for r in ok if r["nees"] is not None]
        rows[method] = {
            "rms_mm": rms_mm,
            "rms_deg": rms_deg,
            "ratio_translation": rms_mm / bound_mm,
            "ratio_rotation": rms_deg / bound_deg,
            "mean_nees": float(np.mean(nees)) if nees else None,
            "failures": len(runs) - len(ok),
            "median_ms": 1e3 * float(np.median([r["time_s"] for r in ok])),
        }
    band = chi2.ppf([0.025, 0.975], 6 * len(trials)) / len(trials)
    return {"bound_mm": bound_mm, "bound_deg": bound_deg, "nees_band": band.tolist(), "methods": rows}


def _print_case(case: str, summary: dict) -> None:
    lo, hi = summary["nees_band"]
    print(
        f"\n## {case}: Cramer-Rao bound {summary['bound_mm']:.3f} mm, {summary['bound_deg']:.4f} deg "
        f"(RMS over trials); NEES 95% band for the mean [{lo:.2f}, {hi:.2f}]"
    )
    header = ("RMS mm", "x CRB", "RMS deg", "x CRB", "NEES", "ms")
    print(
        f"{'method':18s} "
        + " ".join(f"{h:>{w}s}" for h, w in zip(header, (8, 6, 8, 6, 6, 7), strict=True))
        + " failed"
    )
    for method, r in summary["methods"].items():
        if "rms_mm" not in r:
            print(f"{method:18s} all {r['failures']} runs failed: {r['example'][:80]}")
            continue
        nees = "-" if r["mean_nees"] is None else f"{r['mean_nees']:.2f}"
        print(
            f"{method:18s} {r['rms_mm']:8.3f} {r['ratio_translation']:6.2f} {r['rms_deg']:8.4f} "
            f"{r['ratio_rotation']:6.2f} {nees:>6s} {r['median_ms']:7.1f} {r['failures']}"
        )


def acceptance(summaries: dict) -> list[tuple[str, bool]]:
    """The issue's acceptance figures, each with whether it holds."""
    checks = []
    for case in ("robot noise", "no robot noise"):
        rows, (lo, hi) = summaries[case]["methods"], summaries[case]["nees_band"]
        for method, limit in (("batch", 1.1), ("ekf", 1.25), ("iekf", 1.25)):
            r = rows[method]
            worst = max(r["ratio_translation"], r["ratio_rotation"])
            checks.append(
                (f"{case}: {method} RMS <= {limit} x CRB (worst {worst:.2f})", bool(worst <= limit))
            )
        for method in MODEL_METHODS:
            nees = rows[method]["mean_nees"]
            checks.append(
                (f"{case}: {method} mean NEES {nees:.2f} in [{lo:.2f}, {hi:.2f}]", lo <= nees <= hi)
            )
    rows = summaries["robot noise"]["methods"]
    opencv = {m: r for m, r in rows.items() if m in OPENCV_METHODS and "rms_mm" in r}
    best_t = min(opencv, key=lambda m: opencv[m]["rms_mm"])
    best_r = min(opencv, key=lambda m: opencv[m]["rms_deg"])
    gain_t = opencv[best_t]["rms_mm"] / rows["ekf"]["rms_mm"]
    gain_r = opencv[best_r]["rms_deg"] / rows["ekf"]["rms_deg"]
    checks.append(
        (f"ekf translation {gain_t:.2f}x better than the best OpenCV ({best_t}) >= 2.5", gain_t >= 2.5)
    )
    checks.append(
        (f"ekf rotation {gain_r:.2f}x better than the best OpenCV ({best_r}) >= 1.8", gain_r >= 1.8)
    )
    return checks


def plot(summaries: dict, nees: list[float], path: str) -> None:
    """Two panels: RMS error / CRB per method and case, and the ekf NEES against chi-square(6)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (bars, hist) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [2.2, 1]})
    rows = {
        m: r for m, r in summaries["robot noise"]["methods"].items() if "rms_mm" in r and r["failures"] == 0
    }
    names = list(rows)
    x = np.arange(len(names))
    bars.bar(x - 0.2, [rows[m]["ratio_translation"] for m in names], 0.4, label="translation")
    bars.bar(x + 0.2, [rows[m]["ratio_rotation"] for m in names], 0.4, label="rotation")
    bars.axhline(1.0, color="k", lw=1, label="Cramer-Rao bound")
    bars.set_xticks(x, names, rotation=30, ha="right")
    bars.set_ylabel("RMS error / Cramer-Rao bound")
    bars.set_title(f"{len(nees)} trials, robot pose noise in data and model")
    bars.legend()
    grid = np.linspace(0.0, max(25.0, max(nees)), 300)
    hist.hist(nees, bins=40, density=True, alpha=0.6, label="ekf NEES")
    hist.plot(grid, chi2.pdf(grid, 6), "k", label="chi-square, 6 dof")
    hist.set_xlabel("normalised estimation error squared")
    hist.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def time_methods(rounds: int, seed: int) -> dict[str, float]:
    """Median seconds per method for TIMING_VIEWS waypoints x 8 markers."""
    rng = np.random.default_rng(seed)
    X = random_mount(rng)
    observations = scene(X, rng, views=TIMING_VIEWS)
    problem = build_problem(observations, BOARD, INTRINSICS)
    times = {}
    for method in METHODS:
        if method in JOINT_LINEAR_METHODS:
            continue
        samples = []
        for _ in range(rounds):
            start = time.perf_counter()
            METHODS[method](problem, MethodOptions(), observations)
            samples.append(time.perf_counter() - start)
        times[method] = float(np.median(samples))
    return times


def time_against_park(rounds: int, seed: int) -> dict[str, float]:
    """Median seconds over rounds, side by side on one scene of PARK_VIEWS views x 8 markers (a fresh
    problem each round, so first-use caches count): 'ekf' and 'batch' (the methods alone, declared
    noise), 'batch_learned' (run_method's default: noise learned first, then observability) and 'park'
    (OpenCV's Park including the PnP board poses it needs: opencv_calibrate's own time_s)."""
    rng = np.random.default_rng(seed)
    observations = scene(random_mount(rng), rng, views=PARK_VIEWS)
    runs = {
        "ekf": lambda p: METHODS["ekf"](p, MethodOptions(), observations),
        "batch": lambda p: METHODS["batch"](p, MethodOptions(), observations),
        "batch_learned": lambda p: run_method("batch", p, MethodOptions(), observations),
    }
    samples: dict[str, list[float]] = {name: [] for name in (*runs, "park")}
    for _ in range(rounds):
        for name, run in runs.items():
            problem = build_problem(observations, BOARD, INTRINSICS)
            start = time.perf_counter()
            run(problem)
            samples[name].append(time.perf_counter() - start)
        park = METHODS["opencv-park"](build_problem(observations, BOARD, INTRINSICS), MethodOptions(), None)
        samples["park"].append(park.diagnostics["time_s"])
    return {name: float(np.median(values)) for name, values in samples.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--timing-rounds", type=int, default=20)
    parser.add_argument("--json", help="write the summaries to this file")
    parser.add_argument("--plot", help="write a PNG: error / bound per method, ekf NEES histogram")
    parser.add_argument("--page", type=Path, help="also write the tables as this Markdown page")
    args = parser.parse_args(argv)
    if args.json:
        check_json_path(Path(args.json))
    summaries = {}
    printed = io.StringIO()
    with ProcessPoolExecutor(args.workers) as pool:
        for case in CASES:
            jobs = pool.map(run_trial, [case] * args.trials, [args.seed] * args.trials, range(args.trials))
            trials = list(tqdm(jobs, total=args.trials, desc=case, unit="trial"))
            summaries[case] = summarise(trials)
            if case == "robot noise":
                ekf_nees = [t["methods"]["ekf"]["nees"] for t in trials if "nees" in t["methods"]["ekf"]]
            with contextlib.redirect_stdout(printed):
                _print_case(case, summaries[case])
    checks = acceptance(summaries)
    times = time_methods(args.timing_rounds, args.seed)
    with contextlib.redirect_stdout(printed):
        print("\n## acceptance")
        for text, ok in checks:
            print(f"{'PASS' if ok else 'FAIL'}  {text}")
        print(
            f"\n## time for {TIMING_VIEWS} waypoints x 8 markers "
            f"(median of {args.timing_rounds}, one process)"
        )
        for method, seconds in times.items():
            print(f"{method:18s} {1e3 * seconds:8.1f} ms")
    print(printed.getvalue(), end="")
    if args.plot:
        plot(summaries, ekf_nees, args.plot)
        print(f"plot: {args.plot}")
    if args.page is not None:
        picture = args.page.with_suffix(".png")
        plot(summaries, ekf_nees, str(picture))
        options = argv if argv is not None else sys.argv[1:]
        command = " ".join(["python -m hec.bench.estimators", *options])
        body = [
            __doc__.split("\n\n")[0].replace("\n", " "),
            f"![error over the bound, NEES]({picture.name})",
            "```\n" + printed.getvalue().strip("\n") + "\n```",
        ]
        print(f"wrote {write_results_page(args.page, 'Estimators against the bound', command, body)}")
    if args.json:
        write_json(Path(args.json), {"summaries": summaries, "acceptance": checks, "time_s": times})
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())

"""`hec sweep`: the command line of a sweep (run, resume, rerun one trial), its progress
and summary, then the report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands.verbs import HELP
from hec.estimator.common.jsonfile import read_json_object
from hec.support.interrupts import interrupted_exit_code
from hec.sweep.rows import DATASETS_DIR, META_FILE, ROWS_FILE, SweepError, load_rows, read_complete_rows

# The sweep's configuration and runner import the simulator (which picks an OpenGL backend): they
# are imported when a sweep runs, so that `hec` builds its parser on a machine without OpenGL.
if TYPE_CHECKING:
    from hec.sweep.config import SweepConfig


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add `hec sweep`."""
    p = sub.add_parser(
        "sweep",
        help=HELP["sweep"],
        description="Run a reproducible grid of calibration trials: every cell of the sweep file's grid, "
        "`trials` times, every method. Rows go to DIR/rows.csv as trials finish (DIR/sweep.json first).",
    )
    p.add_argument(
        "config", type=Path, metavar="CONFIG", help="sweep TOML file (e.g. models/sweeps/noise.toml)"
    )
    p.add_argument(
        "--out", required=True, type=Path, metavar="DIR", help="output folder (sweep.json, rows.csv)"
    )
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: every core)")
    p.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler instead"
    )
    p.add_argument("--resume", action="store_true", help="continue a sweep in --out: skip the trials done")
    p.add_argument(
        "--rerun",
        metavar="TRIAL_ID",
        help="run one trial (e.g. c03-t0042) again, print its rows and compare them with --out's",
    )
    p.add_argument(
        "--keep-datasets",
        action="store_true",
        help="render fidelity: keep each trial's dataset in DIR/datasets/TRIAL_ID (default: deleted)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _print_rows(rows: list[dict]) -> None:
    for r in rows:
        if r["status"] == "ok":
            print(
                f"  {r['method']:18s} {r['error_translation_mm']:9.4f} mm {r['error_rotation_deg']:9.5f} deg"
                f"  sigma {r['sigma_translation_mm']:8.4f} mm {r['sigma_rotation_deg']:8.5f} deg  "
                f"NEES {r['nees']:7.2f}"
            )
        else:
            print(f"  {r['method']:18s} failed: {r['failure']}")


def _summary(rows: list[dict], config: SweepConfig, most: int = 30) -> None:
    """Median translation error (mm) per cell and method, for the first `most` cells."""
    errors: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        if r["status"] == "ok":
            errors.setdefault((r["cell"], r["method"]), []).append(r["error_translation_mm"])
    swept, methods = config.swept, config.methods
    print("median translation error [mm] per cell (failed runs left out); `hec report` for the full report")
    print(
        f"{'cell':5s} {' '.join(f'{s[:14]:>14s}' for s in swept)} "
        + " ".join(f"{m.removeprefix('opencv-')[:9]:>9s}" for m in methods)
    )
    for cell in config.cells[:most]:
        values = [errors.get((cell.id, m)) for m in methods]
        params = " ".join(f"{str(cell.parameters[s])[:14]:>14s}" for s in swept)
        print(
            f"{cell.id:5s} {params} "
            + " ".join(f"{np.median(e):9.3f}" if e else f"{'-':>9s}" for e in values)
        )
    if len(config.cells) > most:
        print(f"... and {len(config.cells) - most} more cells")


def run(args: argparse.Namespace) -> int:
    """`hec sweep`. Returns 0 when every trial is done, 1 when some were lost, 2 on bad input, 130 on
    Ctrl-C."""
    from hec.sweep.config import SweepConfigError, load_config
    from hec.sweep.runner import available_cores, check_same_config, rerun_trial, run_sweep, same_rows

    config, out_dir = None, Path(args.out)
    try:
        config = load_config(args.config)
        if args.rerun:
            meta = out_dir / META_FILE
            if meta.exists():
                check_same_config(read_json_object(meta, SweepError), config, out_dir)
            keep = out_dir / DATASETS_DIR if args.keep_datasets else None
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
            rows = rerun_trial(config, args.rerun, keep)
            print(f"trial {args.rerun} (seed {rows[0]['seed']}), {config.fidelity}:")
            _print_rows(rows)
            stored = (
                [r for r in load_rows(out_dir) if r["trial_id"] == rows[0]["trial_id"]]
                if meta.exists()
                else []
            )
            if not stored:
                print("no stored rows of this trial to compare with")
                return 0
            differences = same_rows(rows, stored)
            print(
                f"identical to {out_dir / ROWS_FILE} (time_s aside)"
                if not differences
                else "DIFFERS from the stored rows:\n  " + "\n  ".join(differences)
            )
            return 0 if not differences else 1
        if args.workers is not None and args.workers < 1:
            raise SweepError(f"--workers must be >= 1, got {args.workers}")
        total = len(config.cells) * config.trials
        where = (
            f"Dask scheduler {args.scheduler}"
            if args.scheduler
            else f"{args.workers or available_cores()} processes"
        )
        print(
            f"sweep {config.path}: {len(config.cells)} cells x {config.trials} trials = {total} trials, "
            f"{len(config.methods)} methods, {config.fidelity} fidelity, on {where}",
            file=sys.stderr,
        )
        outcome = run_sweep(
            config, out_dir, args.workers, args.scheduler, args.resume, args.keep_datasets, not args.quiet
        )
    except (SweepConfigError, SweepError) as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP (hec.support.interrupts)
        methods = config.methods if config is not None else None
        done = len({r["trial_id"] for r in read_complete_rows(out_dir / ROWS_FILE, methods)})
        print(
            f"\ninterrupted: {done} finished trials are in {out_dir / ROWS_FILE}; "
            "continue with the same command and --resume",
            file=sys.stderr,
        )
        return interrupted_exit_code(exc)
    rows = load_rows(out_dir)
    print(
        f"{outcome.computed} trials run in {outcome.seconds:.1f} s ({outcome.skipped} already done), "
        f"{outcome.failed_runs} failed method runs; {len(rows)} rows in {out_dir / ROWS_FILE}"
    )
    _summary(rows, config)
    if not outcome.lost:
        from hec.sweep.report import ReportError, build_report

        try:
            print(f"report: {build_report(out_dir, rows).html}")
        except ReportError as exc:
            print(f"hec: no report: {exc}", file=sys.stderr)
    if outcome.lost:
        print(
            f"{len(outcome.lost)} trials did not finish (first: {outcome.lost[0][0]}: {outcome.lost[0][1]}); "
            "run again with --resume",
            file=sys.stderr,
        )
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (`python -m hec.commands.sweep CONFIG --out DIR`)."""
    parser = argparse.ArgumentParser(prog="hec")
    add_parser(parser.add_subparsers(dest="command", required=True))
    return run(parser.parse_args(["sweep", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    raise SystemExit(main())

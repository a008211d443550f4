"""Benchmark: the public real eye-in-hand sets (tests/data/real/<set>/, each with its SOURCE.md and
LICENSE) imported with `hec import folder` and calibrated with `hec calibrate --method all`, hec's
default method beside every OpenCV method with one protocol: every method's leave-one-frame-out folds
in the same model (the self-calibrated one, learned once on all frames, and the declared one).

Run: .venv/bin/python -m hec.bench.real_corpus [--page PATH.md]
Prints each set's table (every method: translation, 1-sigma, residual, leave-one-frame-out in px and mm
in the base frame) and the summary (ekf against the OpenCV method that predicts held-out frames best);
--page also writes them as a documentation page. tests/test_real_corpus.py pins these figures.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from hec.commands import table as commands
from hec.support.results_page import markdown_table, write_results_page

REAL = Path(__file__).resolve().parents[2] / "tests" / "data" / "real"

# Each set's `hec import folder` options beyond its images, poses.csv and board.json (files named
# here are in the set's folder). ical's camera is fixed and the board rides on the arm: read as
# eye-in-hand by inverting the poses, its T_flange_cam is T_base_cam (its SOURCE.md).
IMPORT_OPTIONS = {
    "ical_charuco_eye_to_hand": ("--pose-direction", "flange-to-base", "--intrinsics", "camera.yaml"),
    "ur_xtion_chessboard": ("--rotation", "rotvec", "--intrinsics", "camera.yml"),
    "franka_d435_charuco": ("--rotation", "matrix", "--intrinsics", "camera.yaml"),
}
SUMMARY_HEADER = (
    "set",
    "ekf LOO mm",
    "best OpenCV LOO mm",
    "ekf declared",
    "that OpenCV declared",
    "in the same model",
)


def run_hec(argv: list[str]) -> tuple[int, str, str]:
    """`hec ARGV` in this process, its output captured: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = commands.run(commands.build_parser(argv).parse_args(argv))
    return code, out.getvalue(), err.getvalue()


def import_set(name: str, out: Path, poses: Path | None = None, extra: tuple[str, ...] = ()) -> str:
    """`hec import folder` of the set (with another pose file or folder, and extra options, if given)
    into out; returns what it printed. Raises RuntimeError with hec's message if the import fails."""
    folder = REAL / name
    options = [o if not o.endswith((".yaml", ".yml")) else str(folder / o) for o in IMPORT_OPTIONS[name]]
    code, stdout, stderr = run_hec(
        ["import", "folder", str(folder / "images"), "--poses", str(poses or folder / "poses.csv"),
         *options, *extra, "--board", str(folder / "board.json"), "--out", str(out), "--quiet"]
    )  # fmt: skip
    if code != 0:
        raise RuntimeError(f"hec import of {name} failed: {stderr.strip()}")
    return stdout + stderr


def calibrate_json(dataset: Path, method: str) -> dict:
    """`hec calibrate DATASET --method METHOD --json --loo-all` (every method cross-validated, whatever
    the machine's speed): the JSON it writes beside the dataset."""
    out = dataset.parent / f"{dataset.name}-{method}.json"
    code, _, stderr = run_hec(
        ["calibrate", str(dataset), "--method", method, "--json", str(out), "--quiet", "--loo-all"]
    )
    if code != 0:
        raise RuntimeError(f"hec calibrate of {dataset} failed: {stderr.strip()}")
    return json.loads(out.read_text())


def set_table(name: str, result: dict) -> str:
    """One set's `--method all` result as a heading, the frames used and a table of every method."""
    left_out = "; ".join(result["frames_left_out"])
    rows = []
    for m in result["results"]:
        if "error" in m:
            rows.append([m["method"], f"failed: {m['error'].split(' (')[0]}", *[""] * 9])
            continue
        sigma = m["sigma_translation_mm"]
        loo_cells = [
            cell
            for loo in (m["leave_one_frame_out"], m["leave_one_frame_out_declared"])
            for cell in (
                (f"{loo['rms_px']:.3f}", f"{loo['rms_mm']:.3f}")
                if isinstance(loo, dict)
                else ("not run",) * 2
            )
        ]
        rows.append(
            [
                m["method"],
                *(f"{v:.3f}" for v in m["translation_mm"]),
                f"{np.linalg.norm(sigma):.3f}" if sigma else "-",
                f"{m['residual_rms_px']:.3f}",
                *loo_cells,
                f"{m['observations_used']}/{m['observations_rejected']}",
            ]
        )
    header = ["method", "x mm", "y mm", "z mm", "1-sigma mm", "residual px", "LOO px", "LOO mm"]
    header += ["declared LOO px", "declared LOO mm", "used/rejected"]
    model = next(m["leave_one_frame_out"]["model"] for m in result["results"] if m.get("leave_one_frame_out"))
    used = f"{result['frames_used']} frames used" + (f"; left out: {left_out}" if left_out else "") + "."
    footer = f"LOO: every method's folds in the same model, {model}. Declared LOO: in the declared model."
    return "\n\n".join([f"### {name}", used, markdown_table(header, rows), footer])


def summary_cells(name: str, result: dict) -> list[str]:
    """One set's summary row: ekf and the OpenCV method with the best leave-one-frame-out error, in
    the self-calibrated and the declared model (mm), and which wins in the same model."""
    by_method = {r["method"]: r for r in result["results"] if "error" not in r}
    opencv = {m: r for m, r in by_method.items() if m.startswith("opencv")}
    best = min(opencv, key=lambda m: opencv[m]["leave_one_frame_out"]["rms_mm"])
    ekf_loo, best_loo, ekf_declared, best_declared = (
        by_method[m][key]["rms_mm"]
        for key in ("leave_one_frame_out", "leave_one_frame_out_declared")
        for m in ("ekf", best)
    )
    ratio = ekf_loo / best_loo
    verdict = "hec better" if ratio < 1.0 else f"hec loses ({ratio:.2f}x)"
    return [
        name,
        f"{ekf_loo:.3f}",
        f"{best_loo:.3f} ({best})",
        f"{ekf_declared:.3f}",
        f"{best_declared:.3f}",
        verdict,
    ]


def measure() -> tuple[list[str], list[list[str]]]:
    """Import and calibrate every set: (each set's table, the summary rows)."""
    tables, summary = [], []
    with tempfile.TemporaryDirectory() as temporary:
        for name in IMPORT_OPTIONS:
            dataset = Path(temporary) / name
            import_set(name, dataset)
            result = calibrate_json(dataset, "all")
            tables.append(set_table(name, result))
            summary.append(summary_cells(name, result))
    return tables, summary


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--page", type=Path, help="also write the tables as this Markdown page")
    args = parser.parse_args(argv)
    tables, summary = measure()
    summary_table = markdown_table(SUMMARY_HEADER, summary)
    print("\n\n".join([*tables, summary_table]))
    if args.page:
        intro = (
            "Three public real sets (`tests/data/real/`, each with its source and licence), imported with"
            " `hec import folder` and calibrated with `hec calibrate --method all --loo-all`. LOO is the"
            " leave-one-frame-out prediction error of the held-out frame's board, in pixels and in mm in"
            " the base frame, with one protocol for every method: its folds calibrate in the same model,"
            " the self-calibrated one (learned once on all frames) for LOO, the declared one (nothing"
            " learned) for declared LOO. 1-sigma is the root-sum-square of the translation's 1-sigma."
        )
        write_results_page(
            args.page,
            "Public real data",
            f"python -m hec.bench.real_corpus --page {args.page}",
            [intro, "## Summary", summary_table, "## Every method", *tables],
        )


if __name__ == "__main__":
    main()

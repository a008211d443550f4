"""`hec report DIR`: rebuild a sweep's report.html and plots/ from its saved rows
(hec.sweep.report), and print a short table per cell and method."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from hec.commands.verbs import HELP
from hec.sweep.report import PLOTS_DIR, ReportError, build_report, fmt
from hec.sweep.summary import CellSummary


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add `hec report DIR`."""
    p = sub.add_parser("report", help=HELP["report"])
    p.add_argument("dir", type=Path, metavar="DIR", help="the --out folder of `hec sweep`")
    p.add_argument(
        "--page",
        type=Path,
        metavar="PATH.md",
        help="also write the results as a Markdown page (e.g. docs/pages/results/error-budget.md)",
    )


def run(args: argparse.Namespace) -> int:
    """`hec report DIR`: 0 when written, 2 with a message on stderr when DIR has no usable rows."""
    try:
        report = build_report(args.dir)
    except ReportError as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    _print_summary(report.summaries)
    if report.missing:
        print(f"warning: {report.missing}", file=sys.stderr)
    print(
        f"report: {report.html} ({report.images} images embedded; plots in {report.html.parent / PLOTS_DIR})"
    )
    if args.page is not None:
        from hec.sweep.page import write_sweep_page

        try:
            print(f"page: {write_sweep_page(args.dir, report.summaries, args.page, report.missing)}")
        except OSError as exc:
            print(f"hec: error: {args.page}: cannot write the page ({exc.strerror})", file=sys.stderr)
            return 2
    return 0


def _print_summary(summaries: Sequence[CellSummary]) -> None:
    """A short terminal table: per cell and method the success and RMS errors with their ratio."""
    print(
        f"{'cell':12s} {'method':18s} {'ok':>7s} {'RMS mm':>9s} {'x CRB':>8s} {'RMS deg':>9s} {'x CRB':>8s}"
    )
    for s in summaries:
        t, r = s.translation_mm, s.rotation_deg
        print(
            f"{s.cell[:12]:12s} {s.method[:18]:18s} {f'{s.ok}/{s.trials}':>7s} {fmt(t.rms):>9s} "
            f"{fmt(t.ratio, '.3g'):>8s} {fmt(r.rms):>9s} {fmt(r.ratio, '.3g'):>8s}"
        )

"""A benchmark's results as a documentation page (docs/pages/results/*.md): the benchmarks write
their own tables, so the figures in the docs are the ones a command printed, never typed by hand."""

from __future__ import annotations

import datetime
import os
import platform
from collections.abc import Sequence
from pathlib import Path

from hec.estimator.common.files import write_atomic


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table: header cells, then one row of cells (already formatted) per entry."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def machine_line() -> str:
    """Where and when the figures were measured: date, cores, CPU, Python and the machine's load
    (other work running beside the benchmark slows it)."""
    today = datetime.date.today().isoformat()
    cpu = platform.processor() or platform.machine()
    load = os.getloadavg()[1]
    return (
        f"Measured on {today}: {os.cpu_count()} cores ({cpu}), Python {platform.python_version()}; "
        f"load average {load:.1f} over the last 5 minutes at the end."
    )


def write_results_page(path: Path, title: str, command: str, body: Sequence[str]) -> Path:
    """Write a results page: its title, the command that wrote it, the machine, then body's
    paragraphs and tables (Markdown), atomically."""
    head = [
        f"# {title}",
        f"Written by `{command}`; rerun it to measure again (do not edit this page by hand).",
        machine_line(),
    ]
    return write_atomic(Path(path), "\n\n".join([*head, *body]) + "\n")

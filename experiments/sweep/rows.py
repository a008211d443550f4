"""The rows of a sweep: the columns every row has (the contract the runner writes and the
report reads), trial ids, and the rows file on disk.

Output folder:

    sweep.json   written first: the resolved configuration, its cells, the columns, software versions
    rows.csv     one row per trial and method, appended and flushed as each trial finishes; on
                 completion (and on --resume) rewritten sorted, through a rename. load_rows reads it.

Row columns (row_columns): trial_id ('c03-t0042'), cell ('c03'), fidelity, seed ('seed/cell/trial'),
the fidelity's parameters (hec.sweep.config.PARAMETERS, resolved values), method, status
('ok' | 'failed'), failure ('' when ok), error_translation_mm, error_rotation_deg (against the truth),
sigma_translation_mm, sigma_rotation_deg (root-sum-square of the method's three 1-sigmas; NaN without
a covariance), nees (NaN without a covariance), crb_translation_mm, crb_rotation_deg (root-sum-square
of the Cramer-Rao sigmas at the truth; NaN when not observable), time_s (the method's own time),
warnings (how many warnings the result carries, the fit check's and seed-ekf's assumption check's
among them; NaN when failed).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.sweep.parameters import PARAMETERS, parameter_columns

ROWS_FILE, META_FILE, DATASETS_DIR, EXAMPLE_DIR = "rows.csv", "sweep.json", "datasets", "example"
FORMAT, VERSION = "hec-sweep", 1


ID_COLUMNS = ("trial_id", "cell", "fidelity", "seed")
RESULT_COLUMNS = (
    "method",
    "status",
    "failure",
    "error_translation_mm",
    "error_rotation_deg",
    "sigma_translation_mm",
    "sigma_rotation_deg",
    "nees",
    "crb_translation_mm",
    "crb_rotation_deg",
    "time_s",
    "warnings",
)


FLOAT_COLUMNS = RESULT_COLUMNS[3:]
# Columns rows written before they were recorded do not have (a report reads those rows too).
OPTIONAL_COLUMNS = ("warnings",)
TRIAL_ID = re.compile(r"^c(\d+)-t(\d+)$")


class SweepError(RuntimeError):
    """An output folder or a trial id that cannot be used; the message says why."""


def row_columns(fidelity: str) -> list[str]:
    """Every column of a fidelity's rows, in file order."""
    return [*ID_COLUMNS, *parameter_columns(fidelity), *RESULT_COLUMNS]


def trial_id(cell_index: int, trial: int) -> str:
    return f"c{cell_index:02d}-t{trial:04d}"


def format_rows(rows: Iterable[dict], columns: list[str]) -> str:
    """CSV text of rows (floats as repr: they read back bit for bit)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    for row in rows:
        writer.writerow([repr(v) if isinstance(v, float) else v for v in (row[c] for c in columns)])
    return out.getvalue()


def _typed(name: str, text: str) -> Any:
    if name in FLOAT_COLUMNS:
        return float(text)
    if name in PARAMETERS:
        return PARAMETERS[name].kind(text)
    return text


def _sort_key(row: dict, methods: list[str]) -> tuple:
    match = TRIAL_ID.match(row["trial_id"])
    ids = (int(match[1]), int(match[2])) if match else (math.inf, row["trial_id"])
    return (*ids, methods.index(row["method"]) if row["method"] in methods else len(methods))


def read_complete_rows(path: Path, methods: list[str] | None) -> list[dict]:
    """Complete trials from a rows file: a half-written last line, lines that do not parse and
    trials missing a method's row are left out; a trial stored twice keeps its first rows."""
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.split("\n")
    lines = lines[:-1]  # the last piece has no newline: empty, or a half-written line
    if not lines:
        return []
    header = next(csv.reader([lines[0]]))
    trials: dict[str, dict[str, dict]] = {}
    for line in lines[1:]:
        try:
            fields = next(csv.reader([line]))
            if len(fields) != len(header):
                continue
            row = {name: _typed(name, value) for name, value in zip(header, fields, strict=True)}
        except (ValueError, StopIteration, csv.Error):
            continue
        group = trials.setdefault(row["trial_id"], {})
        group.setdefault(row["method"], row)
    rows = [
        row
        for group in trials.values()
        if methods is None or set(methods) <= set(group)
        for method, row in group.items()
        if methods is None or method in methods
    ]
    return sorted(rows, key=lambda r: _sort_key(r, methods or []))


def load_rows(out_dir: Path) -> list[dict]:
    """The rows of a sweep folder, typed (str, float, int as the columns are), sorted by cell, trial and
    method; only trials with every method's row (an interrupted run's partial trial is left out)."""
    out_dir = Path(out_dir)
    meta = read_json_object(out_dir / META_FILE, SweepError, "missing: not a sweep output folder")
    try:
        methods = list(meta["config"]["methods"])
    except (KeyError, TypeError):
        raise SweepError(f"{out_dir / META_FILE}: field 'config.methods' is missing") from None
    return read_complete_rows(out_dir / ROWS_FILE, methods)


def compact_rows(out_dir: Path, columns: list[str], methods: list[str]) -> list[dict]:
    """Rewrite rows.csv with its complete trials only, sorted (through a rename). Returns the rows."""
    rows = read_complete_rows(out_dir / ROWS_FILE, methods)
    write_atomic(out_dir / ROWS_FILE, ",".join(columns) + "\n" + format_rows(rows, columns))
    return rows

"""Tables of numbers per image as people and tools write them: pose files and joint files.

A table is a CSV file (as spreadsheets write it too: a UTF-8 byte-order mark, CRLF line ends, ``,``
``;`` or tab separators, a decimal comma with ``;``; or columns separated by spaces, as
``numpy.savetxt`` writes), a JSON file (a list of ``{"image": NAME, FIELD: [numbers]}`` or an object
``{NAME: [numbers]}``) or a numpy file (``.npy``: an (N, k) or (N, 4, 4) array; ``.npz``: one such
array, or the one named ``FIELD``).

A CSV file may have a header row or not; hec decides from the first row and never guesses: a row
of numbers only is data (no header), a row of names only is a header, anything else is refused.
Columns named ``image`` (or ``frame``) name each row's image, columns named ``time``, ``time_s``,
``timestamp`` or ``stamp`` give its time in seconds; without a header, a column whose every cell is
an image file name is the image column. The other columns, in order, are the row's numbers. Poses
as URScript prints them, ``p[x, y, z, rx, ry, rz]`` (after an image name or alone, a header above
or not), are read as those six numbers.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

NAME_COLUMNS = ("image", "frame")
TIME_COLUMNS = ("time", "time_s", "timestamp", "stamp")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
_SEPARATORS = {",": "comma", ";": "semicolon", "\t": "tab", " ": "spaces"}
_UR_POSE = re.compile(r"\bp\[([^\]]*)\]")  # URScript's pose literal


class PoseFileError(ValueError):
    """A pose or joint file, or a pose convention, that cannot be read; the message names the file,
    the line and the field."""


@dataclass(frozen=True)
class NumberTable:
    """A table's rows. values: (N, k) numbers; names: (N,) image names or None without an image
    column; times_s: (N,) seconds or None without a time column; where: (N,) where each row is in
    the file, for messages ("line 5" of a CSV file, "entry 4" of JSON or numpy, from 0); layout: how
    it was read, in words; columns: (k,) the header's names of the numbers' columns, or None without
    a header; notes: what a person should know (rows that repeat a pose); numbers: (N,) the number in
    each row's own file name (a folder of pose files, one per image: hec.estimator.io.pose_folder)."""

    path: Path
    values: np.ndarray
    names: list[str] | None
    times_s: np.ndarray | None
    where: list[str]
    layout: str
    columns: list[str] | None = None
    notes: list[str] = field(default_factory=list)
    numbers: list[int] | None = None


def read_number_table(path: str | Path, field: str = "pose") -> NumberTable:
    """The rows of a CSV, JSON or numpy table (module doc); field names the numbers ("pose",
    "joints") in JSON and .npz files and in messages."""
    path = Path(path)
    what = "pose" if field == "pose" else "joint"
    if not path.is_file():
        raise PoseFileError(f"{path}: {what} file not found" + (" (a folder?)" if path.is_dir() else ""))
    suffix = path.suffix.lower()
    if suffix == ".json":
        table = _read_json(path, field)
    elif suffix in (".npy", ".npz"):
        table = _read_numpy(path, field)
    else:
        table = _read_csv(path)
    check_table(table, what)
    return table


def number_in_name(path: Path, error: type[Exception], why: str) -> int:
    """The one run of digits in path's name (without its suffix); error naming the file, why the
    number is needed, and whether the name carries none or several."""
    digits = re.findall(r"\d+", path.stem)
    if len(digits) != 1:
        carries = "no number" if not digits else "several numbers"
        raise error(f"{path}: {why}, and {path.name!r} carries {carries}")
    return int(digits[0])


def check_table(table: NumberTable, what: str) -> None:
    """PoseFileError for an empty table, a NaN or an image listed twice; notes for repeated rows."""
    if len(table.values) == 0:
        raise PoseFileError(f"{table.path}: no {what} rows")
    bad = ~np.isfinite(table.values).all(axis=1)
    if bad.any():
        raise PoseFileError(f"{table.path}: {table.where[int(np.argmax(bad))]}: a NaN or infinite number")
    if table.names is not None:
        seen: dict[str, str] = {}
        for name, where in zip(table.names, table.where, strict=True):
            if name in seen:
                raise PoseFileError(
                    f"{table.path}: image {name!r} is listed twice ({seen[name]} and {where}); "
                    "each image takes one row"
                )
            seen[name] = where
    _, first, counts = np.unique(table.values, axis=0, return_index=True, return_counts=True)
    for row in sorted(first[counts > 1]):
        same = [table.where[i] for i in np.flatnonzero((table.values == table.values[row]).all(axis=1))]
        table.notes.append(
            f"{' and '.join(same)} hold the same {what}: a robot that waited, or a row written twice?"
        )


def _decode(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise PoseFileError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); expected CSV, JSON, .npy or .npz"
        ) from None


def _separator(first_line: str) -> str:
    counts = {s: first_line.count(s) for s in (";", "\t", ",")}
    best = max(counts, key=lambda s: counts[s])
    return best if counts[best] else " "


def _read_csv(path: Path) -> NumberTable:
    text = _decode(path)
    numbered = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not numbered:
        raise PoseFileError(f"{path}: the file is empty")
    ur_notation = all(_UR_POSE.search(line) for _, line in numbered[1:] or numbered)
    raw_second = numbered[1][1] if len(numbered) > 1 else ""
    if ur_notation:  # p[x, y, z, rx, ry, rz] as URScript prints a pose: its numbers are the row's
        outside = _UR_POSE.sub("", numbered[0][1])
        sep = _separator(outside) if outside.strip() else ","
        numbered = [
            (n, _UR_POSE.sub(lambda m: sep.join(m.group(1).replace(",", " ").split()), line))
            for n, line in numbered
        ]
    sep = _separator(numbered[0][1])
    if sep == " ":
        rows = [(n, line.split()) for n, line in numbered]
    else:
        parsed = csv.reader(io.StringIO("\n".join(line for _, line in numbered)), delimiter=sep)
        rows = [(n, [cell.strip() for cell in cells]) for (n, _), cells in zip(numbered, parsed, strict=True)]
    decimal_comma = sep == ";"
    first_line, first = rows[0]
    numeric = [_number(cell, decimal_comma) is not None for cell in first]
    if all(numeric) or _image_column(rows) is not None:
        header, data = None, rows
    elif not any(numeric):
        header, data = first, rows[1:]
        if not data:
            raise PoseFileError(f"{path}: a header row and no data rows")
    else:
        raise PoseFileError(
            f"{path}: line {first_line} mixes names and numbers ({', '.join(first[:4])}...): give either a "
            "header row naming every column (image, x, y, ...) or no header at all (numbers only)"
        )
    if ur_notation and header is not None and _UR_POSE.search(raw_second):
        header = _ur_header(header, raw_second, sep)
    width = len(header) if header is not None else len(first)
    if header is not None:
        lowered = [h.lower() for h in header]
        name_column = next((i for i, h in enumerate(lowered) if h in NAME_COLUMNS), None)
        time_column = next((i for i, h in enumerate(lowered) if h in TIME_COLUMNS), None)
    else:
        name_column, time_column = _image_column(rows), None
    names, times, values, where = [], [], [], []
    for line, cells in data:
        if len(cells) != width:
            raise PoseFileError(
                f"{path}: line {line} has {len(cells)} fields, "
                + (f"the header {width}" if header is not None else f"line {first_line} {width}")
            )
        numbers = []
        for column, cell in enumerate(cells):
            if column == name_column:
                continue
            number = _number(cell, decimal_comma)
            if number is None:
                label = f"column '{header[column]}'" if header is not None else f"field {column + 1}"
                raise PoseFileError(f"{path}: line {line}, {label}: not a number: {cell!r}")
            if column == time_column:
                times.append(number)
            else:
                numbers.append(number)
        if name_column is not None:
            names.append(cells[name_column])
        values.append(numbers)
        where.append(f"line {line}")
    layout = (
        ("URScript poses p[...], " if ur_notation else "")
        + f"CSV, {_SEPARATORS[sep]}-separated, "
        + ("a header row" if header is not None else "no header row")
        + ("" if name_column is None else f", image names in column {name_column + 1}")
        + ("" if time_column is None else f", times in column {time_column + 1}")
    )
    return NumberTable(
        path,
        np.array(values, dtype=np.float64),
        names if name_column is not None else None,
        np.array(times) if time_column is not None else None,
        where,
        layout,
        None if header is None else [h for i, h in enumerate(header) if i not in (name_column, time_column)],
    )


def _ur_header(header: list[str], raw_line: str, sep: str) -> list[str]:
    """The header with the column that holds a data line's p[...] pose split into its six numbers'
    columns ("pose" -> "pose x", ..., "pose rz")."""
    prefix = raw_line[: _UR_POSE.search(raw_line).start()]
    column = len(prefix.split()) if sep == " " else prefix.count(sep)
    if column >= len(header):
        return header
    parts = [f"{header[column]} {axis}" for axis in ("x", "y", "z", "rx", "ry", "rz")]
    return header[:column] + parts + header[column + 1 :]


def _number(cell: str, decimal_comma: bool) -> float | None:
    try:
        return float(cell.replace(",", ".") if decimal_comma else cell)
    except ValueError:
        return None


def _image_column(rows: list[tuple[int, list[str]]]) -> int | None:
    """The column whose every cell is an image file name, in a table without a header."""
    first = rows[0][1]
    for column in range(len(first)):
        if all(column < len(cells) and cells[column].lower().endswith(IMAGE_SUFFIXES) for _, cells in rows):
            return column
    return None


def _read_json(path: Path, field: str) -> NumberTable:
    try:
        data = json.loads(_decode(path))
    except json.JSONDecodeError as exc:
        raise PoseFileError(f"{path}: not valid JSON ({exc})") from None
    if isinstance(data, dict):
        entries = [{"image": k, field: v} for k, v in data.items()]
    elif isinstance(data, list):
        entries = data
    else:
        raise PoseFileError(
            f"{path}: expected a list of {{'image', '{field}'}} or an object of {field} lists"
        )
    names, values = [], []
    for i, entry in enumerate(entries):
        row = entry.get(field) if isinstance(entry, dict) else None
        if not isinstance(row, list) or not all(isinstance(v, int | float) for v in np.ravel(row).tolist()):
            hint = " (a 4x4 pose is a list of 4 rows of 4 numbers)" if field == "pose" else ""
            raise PoseFileError(
                f"{path}: entry {i}: field '{field}' should be a list of numbers{hint}, got {row!r}"
            )
        names.append(entry.get("image"))
        values.append(np.ravel(row).tolist())
    if not values or len({len(v) for v in values}) != 1:
        raise PoseFileError(
            f"{path}: every entry's '{field}' must have the same count of numbers (and there must be one)"
        )
    named = any(n is not None for n in names)
    if named and not all(isinstance(n, str) for n in names):
        missing = next(i for i, n in enumerate(names) if not isinstance(n, str))
        raise PoseFileError(f"{path}: entry {missing}: field 'image' should name the image file")
    where = [f"entry {i}" for i in range(len(values))]
    return NumberTable(
        path, np.array(values, dtype=np.float64), names if named else None, None, where, "JSON"
    )


def _read_numpy(path: Path, field: str) -> NumberTable:
    try:
        loaded = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise PoseFileError(f"{path}: not a numpy .npy/.npz file ({exc})") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            keys = list(loaded.keys())
            if len(keys) != 1 and field not in keys:
                raise PoseFileError(
                    f"{path}: holds arrays {keys}; expected one array, or one named '{field}'"
                )
            array = loaded[field if field in keys else keys[0]]
    else:
        array = loaded
    if not np.issubdtype(array.dtype, np.number) or array.ndim not in (2, 3):
        raise PoseFileError(
            f"{path}: expected an (N, k) array of numbers or (N, 4, 4) poses, got {array.dtype} {array.shape}"
        )
    if array.ndim == 3 and array.shape[1:] != (4, 4):
        raise PoseFileError(f"{path}: a stack of poses should be (N, 4, 4), got {array.shape}")
    values = array.reshape(len(array), -1).astype(np.float64)
    layout = "numpy, (N, 4, 4) matrices" if array.ndim == 3 else f"numpy, (N, {values.shape[1]})"
    return NumberTable(path, values, None, None, [f"entry {i}" for i in range(len(values))], layout)

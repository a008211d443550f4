"""A folder of pose files, one per image, as some tools write them (``poses/0.yaml``, ``1.yaml``, ...).

Each file holds one pose: a YAML or JSON mapping of named numbers (``x: 0.11``, ``qz: 0.09``, any
order; nested mappings such as ROS's ``position: {x, y, z}`` are read as ``position.x``), a list of
numbers (a 4x4 matrix as 4 rows of 4), or text with the numbers separated by spaces, commas or
semicolons. Every file must hold the same count, and its name one number: the image with that number
in its name is its image (hec.estimator.io.pairing). Named numbers are then read by their names
(pose_file.columns_by_name), the others in order.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import yaml

from hec.estimator.common.jsonfile import read_text
from hec.estimator.io.pose_table import NumberTable, PoseFileError, check_table, number_in_name

_SEPARATORS = re.compile(r"[\s,;\[\]]+")


def read_pose_folder(folder: Path) -> NumberTable:
    """The (N, k) numbers of a folder's pose files (module doc), in the order of the numbers in their
    names; ``numbers`` holds those numbers and ``columns`` the names of mapping files' numbers."""
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    if not files:
        raise PoseFileError(f"{folder}: an empty pose folder")
    why = "a pose folder's files are named by their image's number ('12.yaml')"
    numbered = sorted((number_in_name(path, PoseFileError, why), path) for path in files)
    repeated = [n for (n, _), (m, _) in zip(numbered, numbered[1:], strict=False) if n == m]
    if repeated:
        twins = [p.name for n, p in numbered if n == repeated[0]]
        raise PoseFileError(f"{folder}: {' and '.join(twins)} carry the same number {repeated[0]}")
    rows = [_read_one(path) for _, path in numbered]
    rows = [_in_order_of(row, rows[0][1]) for row in rows]
    differs = next(
        (i for i, row in enumerate(rows) if (len(row[0]), row[1]) != (len(rows[0][0]), rows[0][1])), None
    )
    if differs is not None:
        raise PoseFileError(
            f"{folder}: {numbered[differs][1].name} holds {_describe(*rows[differs])}, "
            f"{numbered[0][1].name} {_describe(*rows[0])}: every pose file must hold the same"
        )
    kind = "YAML/JSON" if rows[0][1] is not None else "text"
    table = NumberTable(
        folder,
        np.array([values for values, _ in rows], dtype=np.float64),
        None,
        None,
        [path.name for _, path in numbered],
        f"a folder of {len(rows)} pose files ({kind}), one per image",
        rows[0][1],
        numbers=[n for n, _ in numbered],
    )
    check_table(table, "pose")
    return table


def _in_order_of(row: tuple[list[float], list[str] | None], names: list[str] | None) -> tuple:
    """A file's named numbers in the order of the first file's names (files may order keys freely)."""
    values, columns = row
    if columns is None or names is None or sorted(columns) != sorted(names) or len(set(names)) != len(names):
        return row
    return [values[columns.index(name)] for name in names], names


def _describe(values: list[float], columns: list[str] | None) -> str:
    return f"{len(values)} numbers" + (f" named {', '.join(columns)}" if columns else "")


def _read_one(path: Path) -> tuple[list[float], list[str] | None]:
    """One file's numbers and, for a mapping, their names (dotted paths)."""
    text = read_text(path, PoseFileError)
    if path.suffix.lower() in (".yaml", ".yml", ".json"):
        try:
            data = yaml.safe_load(text)  # JSON is YAML
        except yaml.YAMLError as exc:
            raise PoseFileError(f"{path}: not valid YAML/JSON ({' '.join(str(exc).split())})") from None
        values, names = _flatten(data, "", path)
        return values, names if isinstance(data, dict) else None
    cells = [c for c in _SEPARATORS.split(text.strip()) if c]
    values = []
    for cell in cells:
        try:
            values.append(float(cell))
        except ValueError:
            raise PoseFileError(f"{path}: not a number: {cell!r}") from None
    return values, None


def _flatten(data: object, prefix: str, path: Path) -> tuple[list[float], list[str]]:
    if isinstance(data, dict):
        values, names = [], []
        for key, value in data.items():
            v, n = _flatten(value, f"{prefix}{key}.", path)
            values += v
            names += n
        return values, names
    if isinstance(data, list):
        values = np.ravel(np.array(data, dtype=object)).tolist()
        if all(_is_number(v) for v in values):
            return [float(v) for v in values], [f"{prefix}{i}" for i in range(len(values))]
    elif _is_number(data):
        return [float(data)], [prefix.rstrip(".")]
    raise PoseFileError(f"{path}: {prefix.rstrip('.') or 'the file'} holds {data!r}, not numbers")


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)

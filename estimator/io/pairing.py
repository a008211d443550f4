"""Which pose belongs to which image: pairing by an explicit key, never silently by name order.

- ``name``: the pose file's ``image`` column names each row's image;
- ``number``: the number in each image's file name, in natural order (``img_2`` before ``img_10``),
  paired with the pose rows in order, or with the pose file of the same number (a folder of pose
  files, one per image);
- ``time``: each image's time (the number in its file name, seconds by default) with the pose row
  of the nearest time (the pose file's ``time`` column), within a tolerance;
- ``order``: the images in name order with the rows in order; only when asked for.

Without a choice, the image column decides if there is one, else the numbers in the file names; a
folder whose names carry no numbers is refused with what to pass. The pairing used is printed by
the import and written to the dataset's provenance.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.io.pose_table import NumberTable, number_in_name

PAIR_BY = ("name", "number", "time", "order")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_DIGITS = re.compile(r"(\d+)")
_TIME = re.compile(r"\d+(?:\.\d+)?")


class PairingError(ValueError):
    """Images and poses that cannot be paired safely; the message says what to pass."""


@dataclass(frozen=True)
class Pairing:
    """images: (N,) the paired images; rows: (N,) each image's row in the pose table (from 0);
    where: (N,) that row's place in the file ("line 5"); key: how they were paired (PAIR_BY, or
    "file-number" for a folder of pose files)."""

    key: str
    images: list[Path]
    rows: list[int]
    where: list[str]

    def describe(self) -> str:
        """One line: the key, the count, and the first and last pairs."""
        how = {
            "name": "by the pose file's image column",
            "number": "by the number in each image's name (natural order) with the rows in order",
            "file-number": "by the number in each image's name and each pose file's name",
            "time": "by the nearest time",
            "order": "in name order with the rows in order (--pair-by order)",
        }[self.key]
        pairs = [f"{image.name} - {where}" for image, where in zip(self.images, self.where, strict=True)]
        shown = ", ".join(pairs) if len(pairs) <= 3 else f"{pairs[0]}, {pairs[1]}, ..., {pairs[-1]}"
        return f"paired {len(pairs)} images with poses {how}: {shown}"

    def to_dict(self) -> dict:
        return {
            "key": self.key,
            "pairs": [[image.name, where] for image, where in zip(self.images, self.where, strict=True)],
        }


def natural_key(name: str) -> tuple:
    """Sort key of a file name with its digit runs compared as numbers: img_2 before img_10."""
    return tuple(int(part) if part.isdigit() else part for part in _DIGITS.split(name))


def pair_images(
    images: list[Path],
    table: NumberTable,
    pair_by: str | None = None,
    time_tolerance_s: float = 0.02,
    image_time_unit: str = "s",
) -> Pairing:
    """Pair the images of a folder with the rows of its pose table by pair_by (module doc; None:
    the image column if any, else the numbers in the image names)."""
    if pair_by is None:
        pair_by = "name" if table.names is not None else "number"
    if pair_by not in PAIR_BY:
        raise PairingError(f"pairing {pair_by!r}: choose one of {', '.join(PAIR_BY)}")
    if pair_by == "name":
        return _by_name(images, table)
    if pair_by == "time":
        return _by_time(images, table, time_tolerance_s, image_time_unit)
    if pair_by == "number" and table.numbers is not None:
        return _by_file_number(images, table)
    if pair_by == "number":
        unnumbered = [p.name for p in images if not _DIGITS.search(p.stem)]
        if unnumbered:
            raise PairingError(
                f"{table.path} has no 'image' column and {', '.join(unnumbered[:3])} carry no number to "
                "pair by: add an 'image' column naming each row's image, or pass --pair-by order to pair "
                "the images in name order with the rows in order"
            )
        ordered = sorted(images, key=lambda p: natural_key(p.name))
    else:
        ordered = sorted(images)
    if len(ordered) != len(table.values):
        raise PairingError(
            f"{images[0].parent if images else 'the image folder'} has {len(ordered)} images but "
            f"{table.path} {len(table.values)} poses: with no 'image' column every image needs exactly "
            "one row (a pose recorded without its image, or an image without its pose?)"
            + "".join(f"; {note}" for note in table.notes)
        )
    rows = list(range(len(ordered)))
    return Pairing(pair_by, ordered, rows, [table.where[i] for i in rows])


def _by_file_number(images: list[Path], table: NumberTable) -> Pairing:
    """Each image with the pose file carrying the same number (a folder of pose files)."""
    by_number: dict[int, Path] = {}
    why = f"paired with {table.path}'s files by the number in the names"
    for image in images:
        number = number_in_name(image, PairingError, why)
        if number in by_number:
            raise PairingError(f"{image.name} and {by_number[number].name} carry the same number")
        by_number[number] = image
    unposed = sorted(set(by_number) - set(table.numbers))
    unimaged = [w for n, w in zip(table.numbers, table.where, strict=True) if n not in by_number]
    if unposed or unimaged:
        raise PairingError(
            f"{table.path}: "
            + "; ".join(
                part
                for part in (
                    f"no pose file for image {', '.join(by_number[n].name for n in unposed[:3])}"
                    if unposed
                    else "",
                    f"no image for pose file {', '.join(unimaged[:3])}" if unimaged else "",
                )
                if part
            )
            + " (each image needs the pose file of its number)"
        )
    images_in_order = [by_number[n] for n in table.numbers]
    return Pairing("file-number", images_in_order, list(range(len(table.numbers))), table.where)


def _by_name(images: list[Path], table: NumberTable) -> Pairing:
    if table.names is None:
        raise PairingError(f"{table.path}: --pair-by name needs an 'image' column naming each row's image")
    on_disk = {p.name: p for p in images}
    missing = [
        (name, where) for name, where in zip(table.names, table.where, strict=True) if name not in on_disk
    ]
    if missing:
        name, where = missing[0]
        folder = images[0].parent if images else "the image folder"
        raise PairingError(f"{table.path}: {where} names image {name!r}, which is not in {folder}")
    unposed = sorted(set(on_disk) - set(table.names), key=natural_key)
    if unposed:
        raise PairingError(
            f"{images[0].parent}: images without poses in {table.path}: {', '.join(unposed[:5])}"
            + (f" and {len(unposed) - 5} more" if len(unposed) > 5 else "")
        )
    rows = list(range(len(table.names)))
    return Pairing("name", [on_disk[table.names[i]] for i in rows], rows, [table.where[i] for i in rows])


def _by_time(images: list[Path], table: NumberTable, tolerance_s: float, unit: str) -> Pairing:
    if table.times_s is None:
        raise PairingError(
            f"{table.path}: --pair-by time needs a 'time' (or time_s, timestamp, stamp) column in seconds"
        )
    if unit not in TIME_UNITS:
        raise PairingError(f"image time unit {unit!r}: choose one of {', '.join(TIME_UNITS)}")
    if not tolerance_s > 0:
        raise PairingError(f"--time-tolerance must be > 0 seconds, got {tolerance_s}")
    times = []
    for image in images:
        found = _TIME.findall(image.stem)
        if not found:
            raise PairingError(
                f"{image}: --pair-by time reads each image's time from its name; {image.name} has none"
            )
        times.append(float(found[-1]) * TIME_UNITS[unit])
    order = np.argsort(times)
    rows, taken = [], {}
    for i in order:
        gaps = np.abs(table.times_s - times[i])
        row = int(np.argmin(gaps))
        if gaps[row] > tolerance_s:
            raise PairingError(
                f"{images[i].name} (time {times[i]:.6f} s) has no pose within {tolerance_s:g} s in "
                f"{table.path} (nearest: {table.where[row]}, {gaps[row]:.3g} s away): are the clocks and "
                "the time unit (--image-time-unit) the same?"
            )
        if row in taken:
            raise PairingError(
                f"{images[taken[row]].name} and {images[i].name} both pair with {table.where[row]} of "
                f"{table.path}: lower --time-tolerance or check the image times"
            )
        taken[row] = i
        rows.append(row)
    ordered = [images[i] for i in order]
    return Pairing("time", ordered, rows, [table.where[r] for r in rows])

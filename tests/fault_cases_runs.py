"""More cases of the fault table (tests/fault_table.py): hostile output names that must work, option
values no command can use, the verbs that drive a robot or a session, and concurrent runs (a real
process holding the output while the case runs). CASES here is the whole table."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from tests.fault_cases import CASES as FILE_CASES
from tests.fault_cases import OUTPUT_SLOTS, _image_import
from tests.fault_table import Build, Case

CASES = list(FILE_CASES)


def _hostile(slot: str, name: str) -> Build:
    argv, _ = OUTPUT_SLOTS[slot]
    return lambda i, w: (argv(i, w / name), None)


HOSTILE = "a b ü;$(id)'\""
CASES += [
    Case(f"{slot} named {HOSTILE!r}", _hostile(slot, HOSTILE + suffix))
    for slot, suffix in (
        ("export --out", ".json"),
        ("plan --out", ".csv"),
        ("board --out", ".png"),
        ("calibrate --json", ".json"),
        ("verify --json", ".json"),
        ("import easy_handeye2 --out", ""),
    )
]


def _option(argv: object, words: list[str]) -> Build:
    return lambda i, w: (argv(i, w), words)


CASES += [
    Case(f"option {name}", _option(argv, words))
    for name, argv, words in (
        ("plan --views 0", lambda i, w: ["plan", "--views", "0", "--out", str(w / "w.csv")], ["--views"]),
        ("plan --views -3", lambda i, w: ["plan", "--views", "-3", "--out", str(w / "w.csv")], ["--views"]),
        (
            "plan --candidates 2",
            lambda i, w: ["plan", "--views", "4", "--candidates", "2", "--out", str(w / "w.csv")],
            ["--candidates"],
        ),
        (
            "import --depth-scale 0",
            lambda i, w: [*_image_import(i), "--depth-scale", "0", "--out", str(w / "o")],
            ["--depth-scale"],
        ),
        (
            "import --camera nan",
            lambda i, w: [
                "import",
                "visp",
                str(i["visp"]),
                "--board",
                "hec_8qr",
                "--camera",
                *["nan"] * 4,
                "640",
                "480",
                "--out",
                str(w / "o"),
            ],
            ["--camera"],
        ),
        (
            "import --time-tolerance -1",
            lambda i, w: [*_image_import(i), "--time-tolerance", "-1", "--out", str(w / "o")],
            ["--time-tolerance"],
        ),
        (
            "export --link-optical-values zero quaternion",
            lambda i, w: ["export", str(i["cal"]), "--to", "urdf", "--link-optical-values", *["0"] * 7],
            ["--link-optical-values"],
        ),
        (
            "export --method not in the file",
            lambda i, w: ["export", str(i["cal"]), "--to", "json", "--method", "ukf"],
            ["ukf"],
        ),
        (
            "export --child ''",
            lambda i, w: ["export", str(i["cal"]), "--to", "json", "--child", ""],
            ["--child"],
        ),
        (
            "export --parent 'a b'",
            lambda i, w: ["export", str(i["cal"]), "--to", "json", "--parent", "a b"],
            ["--parent"],
        ),
        (
            "calibrate --robot-sigma-mm nan",
            lambda i, w: ["calibrate", str(i["ds"]), "--robot-sigma-mm", "nan"],
            ["--robot-sigma-mm"],
        ),
        (
            "sweep --workers 0",
            lambda i, w: ["sweep", str(i["sweep_config"]), "--out", str(w / "s"), "--workers", "0"],
            ["--workers"],
        ),
        ("board --dpi 0", lambda i, w: ["board", "--out", str(w / "b.png"), "--dpi", "0"], ["--dpi"]),
        ("simulate --seed -1", lambda i, w: ["simulate", "--out", str(w / "o"), "--seed", "-1"], ["--seed"]),
        (
            "import easy_handeye2 --pose-direction wrong",
            lambda i, w: [
                "import",
                "easy_handeye2",
                str(i["samples"]),
                "--out",
                str(w / "o"),
                "--pose-direction",
                "flange-to-base",
            ],
            ["--pose-direction base-to-flange"],
        ),
        (
            "sweep into a finished sweep",
            lambda i, w: ["sweep", str(i["sweep_config"]), "--out", str(i["sweep"])],
            ["--resume"],
        ),
    )
]


def _with_file(name: str, content: bytes, argv: object) -> Build:
    """A case with work/name holding content first (words: name)."""

    def build(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
        (w / name).write_bytes(content)
        return argv(i, w), [name]

    return build


RANDOM = np.random.default_rng(3).bytes(400)
SIM = ["--sim", "--yes", "--no-live"]
CASES += [
    Case(
        "record --out an existing file",
        _with_file("f", b"x\n", lambda i, w: ["record", *SIM, "--out", str(w / "f")]),
    ),
    Case(
        "record --waypoints missing",
        _option(
            lambda i, w: ["record", *SIM, "--waypoints", str(w / "wp.csv"), "--out", str(w / "r")], ["wp.csv"]
        ),
    ),
    Case(
        "record --waypoints random bytes",
        _with_file(
            "wp.csv",
            RANDOM,
            lambda i, w: ["record", *SIM, "--waypoints", str(w / "wp.csv"), "--out", str(w / "r")],
        ),
    ),
    Case(
        "run --waypoints empty",
        _with_file(
            "wp.csv", b"", lambda i, w: ["run", *SIM, "--waypoints", str(w / "wp.csv"), "--out", str(w / "r")]
        ),
    ),
    Case(
        "run --cell random bytes",
        _with_file(
            "cell.toml",
            RANDOM,
            lambda i, w: [
                "run",
                "--robot",
                "127.0.0.1",
                "--cell",
                str(w / "cell.toml"),
                "--out",
                str(w / "r"),
            ],
        ),
    ),
    Case(
        "teach with no controller",
        _option(lambda i, w: ["teach", "--robot", "127.0.0.1", "--out", str(w / "t.csv")], ["127.0.0.1"]),
    ),
    Case(
        "teach --cell random bytes",
        _with_file(
            "cell.toml",
            RANDOM,
            lambda i, w: ["teach", "--cell", str(w / "cell.toml"), "--out", str(w / "t.csv")],
        ),
    ),
    Case(
        "regress --baseline missing",
        _option(lambda i, w: ["regress", "--baseline", str(w / "b.json")], ["b.json"]),
    ),
    Case(
        "regress --baseline random bytes",
        _with_file("b.json", RANDOM, lambda i, w: ["regress", "--baseline", str(w / "b.json")]),
    ),
    Case(
        "demo --out an existing file", _with_file("f", b"x\n", lambda i, w: ["demo", "--out", str(w / "f")])
    ),
]
CASES.append(
    Case(
        "run --sim with a cell file",
        _with_file(
            "cell.toml",
            b"",
            lambda i, w: ["run", *SIM, "--cell", str(w / "cell.toml"), "--out", str(w / "r")],
        ),
    )
)


# Concurrent runs: a real process holds the output while the case runs.
HOLD_WRITER = """
import sys
from hec.estimator.io.dataset import DatasetWriter
with DatasetWriter(sys.argv[1] + "/o", None, None, 0.001, "import") as writer:
    print("ready", flush=True)
    sys.stdin.readline()
"""
HOLD_SWEEP = """
import os, sys
from hec.estimator.io.lock import acquire_lock
os.makedirs(sys.argv[1] + "/s", exist_ok=True)
acquire_lock(sys.argv[1] + "/s", "a sweep")
print("ready", flush=True)
sys.stdin.readline()
"""


def _copied_sweep(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
    shutil.copytree(i["sweep"], w / "s", dirs_exist_ok=True)
    return ["sweep", str(i["sweep_config"]), "--out", str(w / "s"), "--resume", "--quiet"], [
        "a sweep is in progress"
    ]


def _making_sweep_folder(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
    return ["sweep", str(i["sweep_config"]), "--out", str(w / "s"), "--quiet"], ["a sweep is in progress"]


CASES += [
    Case(
        "import into a folder another import is writing",
        lambda i, w: ([*_image_import(i), "--no-check", "--out", str(w / "o")], ["another hec run"]),
        holder=HOLD_WRITER,
    ),
    Case(
        "import easy_handeye2 into a folder another import is writing",
        lambda i, w: (
            ["import", "easy_handeye2", str(i["samples"]), "--out", str(w / "o")],
            ["another hec run"],
        ),
        holder=HOLD_WRITER,
    ),
    Case(
        "simulate into a folder an import is writing",
        lambda i, w: (
            ["simulate", "--scenario", str(i["scenario"]), "--out", str(w / "o"), "--quiet"],
            ["another hec run"],
        ),
        holder=HOLD_WRITER,
    ),
    Case("sweep --resume while the sweep runs", _copied_sweep, holder=HOLD_SWEEP),
    Case("sweep into a folder a sweep holds", _making_sweep_folder, holder=HOLD_SWEEP),
]

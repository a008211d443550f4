"""The cases of the fault table (tests/fault_table.py): every verb's input files missing, a folder
for a file (and the other way), empty, random bytes or the wrong kind of content; its outputs where
they cannot go (no folder, a name too long, an input, a read-only or full disk, a folder); hostile
names that must work; and option values no command can use."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from tests.fault_table import Build, Case
from tests.hec_cli import run_hec, scenario_file

REPO = Path(__file__).resolve().parent.parent
TINY_SWEEP = (
    'fidelity = "measurements"\nseed = 5\ntrials = 1\nmethods = ["opencv-park"]\n\n[fixed]\nwaypoints = 6\n'
)


def build_inputs(root: Path) -> dict[str, Path]:
    """The inputs every case reads (none is ever to change): a 4-view simulated dataset, detected;
    its calibration; it as an image folder, ViSP's layout and easy_handeye2 pairs; a camera file,
    a board, a scenario, a sweep file and a finished sweep."""
    from hec.bench.pose_pairs import rendered_pairs
    from hec.estimator.io.dataset import load_dataset
    from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
    from hec.estimator.io.layouts import write_easy_handeye_samples, write_folder, write_visp
    from hec.estimator.io.pose_file import PoseConvention

    root.mkdir(parents=True)
    scenario = scenario_file(root / "scenario", 4)
    assert run_hec(["simulate", "--out", str(root / "ds"), "--scenario", str(scenario), "--quiet"])[0] == 0
    assert run_hec(["detect", str(root / "ds"), "--quiet"])[0] == 0
    argv = ["calibrate", str(root / "ds"), "--method", "ekf", "--no-loo", "--quiet"]
    assert run_hec([*argv, "--json", str(root / "cal.json")])[0] == 0
    dataset = load_dataset(root / "ds")
    pngs = [(dataset.root / row["rgb"]).read_bytes() for row in dataset.rows]
    T = np.array([row["T_base_flange"] for row in dataset.rows])
    joints = np.array([row["joints"] for row in dataset.rows])
    write_folder(root / "folder", pngs, T, PoseConvention("quat-wxyz", "rad", "m", "base-to-flange"), joints)
    write_visp(root / "visp", pngs, T)
    write_easy_handeye_samples(root / "cell.samples", rendered_pairs(dataset))
    write_opencv_intrinsics(root / "camera.yaml", dataset.intrinsics)
    shutil.copy(REPO / "models" / "boards" / "hec_8qr.json", root / "board.json")
    (root / "sweep.toml").write_text(TINY_SWEEP)
    argv = ["sweep", str(root / "sweep.toml"), "--out", str(root / "sweep"), "--workers", "1", "--quiet"]
    assert run_hec(argv)[0] == 0
    names = {"ds": "ds", "cal": "cal.json", "folder": "folder", "visp": "visp", "samples": "cell.samples"}
    names |= {"camera": "camera.yaml", "board": "board.json", "scenario": "scenario/scenario.toml"}
    names |= {"sweep_config": "sweep.toml", "sweep": "sweep"}
    return {"root": root} | {k: root / v for k, v in names.items()}


def _image_import(i: dict[str, Path], layout: str = "folder") -> list[str]:
    source = i["folder"] / "images" if layout == "folder" else i[layout]
    argv = ["import", layout, str(source), "--board", "hec_8qr", "--intrinsics", str(i["camera"])]
    return argv + (["--poses", str(i["folder"] / "poses.csv")] if layout == "folder" else []) + ["--quiet"]


# Each input slot: how a command takes a file in place of the right one (argv given the inputs, the
# work folder and that file).
FILE_SLOTS: dict[str, object] = {
    "export": lambda i, w, f: ["export", str(f), "--to", "json", "--assume-zero-offset"],
    "rehearse --waypoints": lambda i, w, f: [
        "rehearse",
        "--out",
        str(w / "rehearsal"),
        "--waypoints",
        str(f),
        "--dry-run",
    ],
    "export --link-optical": lambda i, w, f: [
        "export",
        str(i["cal"]),
        "--to",
        "urdf",
        "--link-optical",
        str(f),
    ],
    "verify CALIBRATION": lambda i, w, f: ["verify", str(f), str(i["ds"]), "--quiet"],
    "calibrate --prior": lambda i, w, f: [
        "calibrate",
        str(i["ds"]),
        "--prior",
        str(f),
        "--quiet",
        "--no-loo",
    ],
    "import --poses": lambda i, w, f: [*_image_import(i), "--poses", str(f), "--out", str(w / "o")],
    "import --intrinsics": lambda i, w, f: [*_image_import(i), "--intrinsics", str(f), "--out", str(w / "o")],
    "import --joints": lambda i, w, f: [*_image_import(i), "--joints", str(f), "--out", str(w / "o")],
    "import easy_handeye2": lambda i, w, f: ["import", "easy_handeye2", str(f), "--out", str(w / "o")],
    "board --board": lambda i, w, f: ["board", "--board", str(f), "--out", str(w / "b.png")],
    "simulate --scenario": lambda i, w, f: [
        "simulate",
        "--scenario",
        str(f),
        "--out",
        str(w / "o"),
        "--quiet",
    ],
    "plan --scenario": lambda i, w, f: ["plan", "--scenario", str(f), "--out", str(w / "w.csv")],
    "plan --calibration": lambda i, w, f: ["plan", "--calibration", str(f), "--out", str(w / "w.csv")],
    "sweep CONFIG": lambda i, w, f: ["sweep", str(f), "--out", str(w / "s"), "--workers", "1", "--quiet"],
}
EMPTY_IS_DEFAULT = (
    FILE_SLOTS["simulate --scenario"],
    FILE_SLOTS["plan --scenario"],
    FILE_SLOTS["sweep CONFIG"],
)
FOLDER_SLOTS: dict[str, object] = {
    "calibrate DATASET": lambda i, w, f: ["calibrate", str(f), "--quiet", "--no-loo"],
    "detect DATASET": lambda i, w, f: ["detect", str(f), "--quiet"],
    "verify DATASET": lambda i, w, f: ["verify", str(i["cal"]), str(f), "--quiet"],
    "import folder SOURCE": lambda i, w, f: (
        [*_image_import(i), "--out", str(w / "o")][:2]
        + [str(f)]
        + [*_image_import(i), "--out", str(w / "o")][3:]
    ),
    "import visp SOURCE": lambda i, w, f: (
        [*_image_import(i, "visp")[:2], str(f), *_image_import(i, "visp")[3:]] + ["--out", str(w / "o")]
    ),
    "import --depth": lambda i, w, f: [*_image_import(i), "--depth", str(f), "--out", str(w / "o")],
    "report DIR": lambda i, w, f: ["report", str(f)],
}


def _file_fault(kind: str, slot) -> Build:
    """The file fault kind in slot; the refusal must name the file."""

    def build(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
        bad = w / "bad file.json"
        if kind == "empty" and slot in EMPTY_IS_DEFAULT:  # an empty TOML file: every default
            bad.write_bytes(b"")
            return slot(i, w, bad), None
        if kind == "missing":
            bad = w / "missing.json"
        elif kind == "a folder":
            bad.mkdir()
        elif kind == "empty":
            bad.write_bytes(b"")
        elif kind == "random bytes":
            bad.write_bytes(np.random.default_rng(7).bytes(512))
        else:  # the wrong kind of content: a JSON list of numbers
            bad.write_text("[1, 2, 3]\n")
        return slot(i, w, bad), [bad.name]

    return build


def _folder_fault(kind: str, slot) -> Build:
    def build(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
        bad = w / "bad folder"
        if kind == "a file":
            bad.write_text("not a folder\n")
        elif kind == "empty":
            bad.mkdir()
        return slot(i, w, bad), [bad.name]

    return build


CASES: list[Case] = [
    Case(f"{slot} {kind}", _file_fault(kind, build))
    for slot, build in FILE_SLOTS.items()
    for kind in ("missing", "a folder", "empty", "random bytes", "wrong content")
] + [
    Case(f"{slot} {kind}", _folder_fault(kind, build))
    for slot, build in FOLDER_SLOTS.items()
    for kind in ("missing", "a file", "empty")
]

# Each output slot: (argv given the inputs and the output path, what the output is: 'file' or 'folder').
OUTPUT_SLOTS: dict[str, tuple[object, str]] = {
    "export --out": (
        lambda i, o: ["export", str(i["cal"]), "--to", "json", "--assume-zero-offset", "--out", str(o)],
        "file",
    ),
    "plan --out": (lambda i, o: ["plan", "--views", "4", "--candidates", "50", "--out", str(o)], "file"),
    "board --out": (lambda i, o: ["board", "--out", str(o.with_suffix(".png"))], "file"),
    "board --definition": (
        lambda i, o: ["board", "--out", str(o.parent / "b.png"), "--definition", str(o)],
        "file",
    ),
    "calibrate --json": (
        lambda i, o: [
            "calibrate",
            str(i["ds"]),
            "--method",
            "opencv-park",
            "--no-loo",
            "--quiet",
            "--json",
            str(o),
        ],
        "file",
    ),
    "calibrate --report": (
        lambda i, o: [
            "calibrate",
            str(i["ds"]),
            "--method",
            "opencv-park",
            "--no-loo",
            "--quiet",
            "--report",
            str(o),
        ],
        "folder",
    ),
    "verify --json": (
        lambda i, o: ["verify", str(i["cal"]), str(i["ds"]), "--quiet", "--json", str(o)],
        "file",
    ),
    "import --out": (lambda i, o: [*_image_import(i), "--no-check", "--out", str(o)], "folder"),
    "import easy_handeye2 --out": (
        lambda i, o: ["import", "easy_handeye2", str(i["samples"]), "--out", str(o)],
        "folder",
    ),
    "simulate --out": (
        lambda i, o: ["simulate", "--scenario", str(i["scenario"]), "--out", str(o), "--quiet"],
        "folder",
    ),
    "sweep --out": (
        lambda i, o: ["sweep", str(i["sweep_config"]), "--out", str(o), "--workers", "1", "--quiet"],
        "folder",
    ),
}
# Outputs given as one of the command's own inputs (a copy in the work folder): (the input's key,
# the file inside it, if a folder).
OVER_INPUT: dict[str, tuple[str, str]] = {
    "export --out": ("cal", ""),
    "calibrate --json": ("ds", "dataset.json"),
    "verify --json": ("cal", ""),
    "import --out": ("folder", ""),
    "board --definition": ("board", ""),
}


def _output_fault(kind: str, slot: str) -> Build:
    argv, what = OUTPUT_SLOTS[slot]

    def build(i: dict[str, Path], w: Path) -> tuple[list[str], list[str]]:
        if kind == "no folder":  # a folder output is made with its parents; a file's folder must exist
            out = w / "no such folder" / "out.json"
            return argv(i, out), ["no such folder"] if what == "file" else None
        if kind == "name too long":
            out = w / ("n" * 300 + ".json")
            return argv(i, out), ["n" * 100, "too long"]
        if kind in ("read-only", "full"):
            return argv(i, w / "out.json"), [str(w)]
        if kind == "wrong kind":  # a folder for a file, a file for a folder
            out = w / "out.json"
            out.mkdir() if what == "file" else out.write_text("the user's\n")
            return argv(i, out), ["out.json"]
        key, inner = OVER_INPUT[slot]
        source = i[key]
        copy = w / source.name
        shutil.copytree(source, copy) if source.is_dir() else shutil.copy(source, copy)
        if slot == "import --out":  # the image folder's own folder, with its source inside
            args = [a.replace(str(source), str(copy)) for a in argv(i, copy)]
            return args, [str(copy)]
        if slot == "calibrate --json" or slot == "calibrate --report":
            args = [a if a != str(i["ds"]) else str(copy) for a in argv(i, copy / inner if inner else copy)]
            return args, [copy.name]
        if slot == "board --definition":
            return ["board", "--board", str(copy), "--out", str(w / "b.png"), "--definition", str(copy)], [
                copy.name
            ]
        args = [a if a != str(source) else str(copy) for a in argv(i, copy)]
        return args, [copy.name]

    return build


def _fs(kind: str) -> str | None:
    return {"read-only": "ro", "full": "full"}.get(kind)


CASES += [
    Case(f"{slot} {kind}", _output_fault(kind, slot), _fs(kind))
    for slot in OUTPUT_SLOTS
    for kind in ("no folder", "name too long", "read-only", "full", "wrong kind")
] + [Case(f"{slot} over its input", _output_fault("input", slot)) for slot in OVER_INPUT]

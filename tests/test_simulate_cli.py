"""`hec simulate` and `hec board` end to end: scenario files, errors, atomic output, determinism,
the dataset format round trip, waypoint files, previews and the printable board.

Runs render short waypoint files (2-4 views taken from the default trajectory) to stay fast.
"""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from hec.cli import main
from hec.estimator.common.models import models_dir
from hec.estimator.geometry.transforms import pose_error, transform_from_xyz_quat
from hec.estimator.geometry.waypoints import (
    Waypoint,
    WaypointFileError,
    read_waypoint_file,
    write_waypoint_file,
)
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.frames import DatasetError
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints, simulate
from tests.hec_cli import run_hec

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "models" / "scenarios"
FILE_SCENARIO = '[trajectory]\nkind = "file"\nfile = "waypoints.csv"\n'
# Indices into the default trajectory of views the UR5 reaches from one another.
GOOD_VIEWS = (0, 1, 9)


def _good(*views: int) -> list[Waypoint]:
    default = scenario_waypoints(Scenario())
    return [default[v] for v in views]


def _far(offset_m: float = 3.0) -> Waypoint:
    """A flange pose 3 m away from the first default view: out of the arm's reach."""
    T = scenario_waypoints(Scenario())[0].T_base_flange.copy()
    T[:3, 3] += (offset_m, 0.0, 0.0)
    return Waypoint(0, "far away", T_base_flange=T)


def _write_case(folder: Path, waypoints: list[Waypoint], toml: str = FILE_SCENARIO) -> Path:
    """A scenario file in folder whose trajectory is waypoints.csv beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    write_waypoint_file(folder / "waypoints.csv", waypoints)
    (folder / "scenario.toml").write_text(toml)
    return folder / "scenario.toml"


def _leftovers(out: Path) -> list[str]:
    """Temporary siblings of out (.NAME.partial-*, .NAME.old-*)."""
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def _tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _reported_poses(root: Path) -> list[np.ndarray]:
    """(7,) x_m..qz of every row of frames.csv, read with the csv module."""
    with open(root / "frames.csv", newline="") as f:
        return [
            np.array([float(r[c]) for c in ("x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")])
            for r in csv.DictReader(f)
        ]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Three runs of [good, unreachable, good, good]: seed 0 twice (scenario seed), seed 1 once."""
    tmp = tmp_path_factory.mktemp("sim")
    scenario = _write_case(tmp / "case", [_good(0)[0], _far(), *_good(*GOOD_VIEWS[1:])])
    result = {"scenario": scenario, "waypoints": _good(*GOOD_VIEWS)}
    for name, extra in (("a", []), ("b", []), ("c", ["--seed", "1"])):
        out = tmp / name
        result[name] = (
            out,
            *run_hec(["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet", *extra]),
        )
    return result


# --- scenario files --------------------------------------------------------------------------


def test_default_toml_spells_out_the_code_defaults() -> None:
    loaded = load_scenario(SCENARIOS / "default.toml")
    assert loaded.to_dict() == Scenario().to_dict()
    assert loaded.base_dir == str(SCENARIOS)
    text = (SCENARIOS / "default.toml").read_text()
    for key in ("fx", "fy", "cx", "cy", "file"):
        assert re.search(rf"^# {key} = ", text, re.MULTILINE), f"optional key {key} not shown commented out"


def test_paper_toml_is_the_paper_trajectory() -> None:
    paper = load_scenario(SCENARIOS / "paper.toml")
    assert paper.trajectory.kind == "paper"
    assert paper.model_copy(update={"trajectory": Scenario().trajectory}).to_dict() == Scenario().to_dict()
    waypoints = scenario_waypoints(paper)
    rotations = {tuple(np.round(w.T_base_flange[:3, :3], 12).ravel()) for w in waypoints}
    assert len(waypoints) == 15 and len(rotations) == 1


@pytest.mark.parametrize(
    ("toml", "csv_text", "expected"),
    [
        ('robot = "ur5"\n[camera]\nwidht = 640\n', None, ["camera.widht", "unknown key"]),
        ('[noise.depth]\nsubpixel = "abc"\n', None, ["noise.depth.subpixel", "'abc'"]),
        ("[noise.depth]\nsubpixel = \n", None, ["not valid TOML", "line 2"]),
        (FILE_SCENARIO, "x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0.5,1,0,0,0\n0,0,abc,1,0,0,0\n", ["waypoint 1"]),
    ],
    ids=["unknown-key", "wrong-type", "invalid-toml", "bad-waypoint-file"],
)
def test_bad_scenario_exits_2_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], toml: str, csv_text: str | None, expected: list[str]
) -> None:
    scenario = tmp_path / "bad.toml"
    scenario.write_text(toml)
    named = scenario
    if csv_text is not None:
        named = tmp_path / "waypoints.csv"
        named.write_text(csv_text)
    out = tmp_path / "out"
    assert main(["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(named) in err
    for text in expected:
        assert text in err
    assert not out.exists() and _leftovers(out) == []


# --- the output folder --------------------------------------------------------------------------


def test_existing_out_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = _write_case(tmp_path / "case", _good(0, 9))
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    argv = ["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet"]
    assert main(argv) == 2
    assert "already exists" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "precious"
    assert main([*argv, "--force"]) == 2  # --force replaces only a dataset hec wrote
    assert "exists and is not a hec dataset" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "precious"
    (out / "keep.txt").unlink()
    assert main(argv) == 2 and main([*argv, "--force"]) == 0  # an empty folder: nothing to lose
    assert main([*argv, "--force"]) == 0  # a dataset hec wrote
    assert len(load_dataset(out)) == 2
    assert _leftovers(out) == []


class _Crash(Exception):
    pass


@pytest.mark.parametrize("existing", [False, True], ids=["new-out", "forced-over-existing"])
def test_crash_mid_run_leaves_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool
) -> None:
    scenario = _write_case(tmp_path / "case", _good(0, 9))
    out = tmp_path / "out"
    if existing:  # a dataset of an earlier run (--force replaces only those) with a file of the user's
        out.mkdir()
        (out / "dataset.json").write_text('{"format": "hec-dataset"}')
        (out / "keep.txt").write_text("precious")
    original = SimCell.capture
    captured: list[int] = []
    partial_at_crash: list[Path] = []

    def capture_then_crash(self: SimCell, rng: np.random.Generator | None = None) -> tuple:
        """The real capture for the first frame, then a crash (with the first frame on disk)."""
        if captured:
            partial_at_crash.extend(out.parent.glob(f".{out.name}.partial-*/rgb/*.png"))
            raise _Crash("simulated crash after the first frame")
        captured.append(1)
        return original(self, rng)

    monkeypatch.setattr(SimCell, "capture", capture_then_crash)
    with pytest.raises(_Crash):
        main(["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet", "--force"])
    assert len(partial_at_crash) == 1, "the first frame should have been written to a partial folder"
    assert _leftovers(out) == []
    if existing:
        assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "keep.txt"]
        assert (out / "keep.txt").read_text() == "precious"
    else:
        assert not out.exists()


def test_all_waypoints_unreachable_leaves_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = load_scenario(_write_case(tmp_path / "case", [_far(3.0), _far(-3.0)]))
    out = tmp_path / "out"
    with pytest.raises(Exception, match="no waypoint could be used"):
        simulate(scenario, out, seed=0, progress=False)
    err = capsys.readouterr().err
    assert "waypoint 0 (far away) skipped: out of reach" in err
    assert "waypoint 1 (far away) skipped: out of reach" in err
    assert not out.exists() and _leftovers(out) == []


def test_all_waypoints_unreachable_cli_exit_code(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = _write_case(tmp_path / "case", [_far(3.0), _far(-3.0)])
    out = tmp_path / "out"
    assert main(["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "hec: error:" in err and "no waypoint could be used" in err
    assert not out.exists() and _leftovers(out) == []


# --- skipped waypoints, determinism, the dataset format ---------------------------------------------


def test_unreachable_waypoint_is_skipped_and_reported(runs: dict) -> None:
    out, code, stdout, stderr = runs["a"]
    assert code == 0
    assert "skipped waypoint 1: out of reach" in stdout
    assert "waypoint 1 (far away) skipped: out of reach" in stderr
    meta = json.loads((out / "dataset.json").read_text())
    skipped = meta["simulation"]["skipped_waypoints"]
    assert [s["index"] for s in skipped] == [1] and "out of reach" in skipped[0]["reason"]
    assert meta["simulation"]["waypoints"] == 4 and meta["frame_count"] == 3
    ds = load_dataset(out)
    assert (
        len(ds) == 3 and len(list((out / "rgb").iterdir())) == 3 and len(list((out / "depth").iterdir())) == 3
    )
    for T_true, target in zip(ds.ground_truth.T_base_flange, runs["waypoints"], strict=True):
        dt, dr = pose_error(T_true, target.T_base_flange)
        assert dt < 1e-6 and dr < 1e-6


def test_same_seed_gives_identical_bytes(runs: dict) -> None:
    a, b = _tree_bytes(runs["a"][0]), _tree_bytes(runs["b"][0])
    assert {"dataset.json", "frames.csv", "ground_truth.json", "rgb/000002.png", "depth/000002.png"} <= set(a)
    assert a.keys() == b.keys()
    for name in a:
        assert a[name] == b[name], f"{name} differs between two runs with the same seed"


def test_other_seed_changes_the_noise(runs: dict) -> None:
    a, c = runs["a"][0], runs["c"][0]
    assert json.loads((c / "dataset.json").read_text())["simulation"]["seed"] == 1
    for i in range(3):
        rgb_a = cv2.imread(str(a / f"rgb/{i:06d}.png"))
        rgb_c = cv2.imread(str(c / f"rgb/{i:06d}.png"))
        assert np.any(rgb_a != rgb_c)
        # Only the noise differs: the images agree on average to well under a grey level.
        assert abs(float(rgb_a.mean()) - float(rgb_c.mean())) < 1.0
    for pose_a, pose_c in zip(_reported_poses(a), _reported_poses(c), strict=True):
        assert np.any(pose_a != pose_c)
    truth_a, truth_c = load_dataset(a).ground_truth, load_dataset(c).ground_truth
    for T_a, T_c in zip(truth_a.T_base_flange, truth_c.T_base_flange, strict=True):
        np.testing.assert_array_equal(T_a, T_c)


def test_dataset_round_trip(runs: dict) -> None:
    out = runs["a"][0]
    scenario = load_scenario(runs["scenario"])
    ds = load_dataset(out)
    assert len(ds) == ds.metadata["frame_count"] == 3
    assert len(ds.ground_truth.T_base_flange) == 3
    np.testing.assert_allclose(ds.ground_truth.T_flange_cam, scenario.mount.transform(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds.ground_truth.T_base_board, scenario.board.transform(), rtol=0, atol=1e-12)
    scale = ds.depth_scale_m
    assert scale == scenario.noise.depth_quantisation.depth_scale_m
    sigma_t = scenario.noise.robot_pose.translation_sigma_m
    for i, reported in enumerate(_reported_poses(out)):
        frame = ds.frame(i)
        assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == np.uint8
        T_reported = transform_from_xyz_quat(reported[:3], reported[3:])
        np.testing.assert_allclose(frame.T_base_flange, T_reported, rtol=0, atol=1e-12)
        dt, dr = pose_error(frame.T_base_flange, ds.ground_truth.T_base_flange[i])
        assert 1e-3 * sigma_t < dt < 1e-3, f"frame {i}: reported vs true translation {dt} m"
        assert 0 < np.degrees(dr) < 0.1, f"frame {i}: reported vs true rotation {np.degrees(dr)} deg"
        depth = frame.depth_m
        assert depth.dtype == np.float32 and depth.shape == (480, 640)
        assert np.any(depth == 0) and np.count_nonzero(depth) > depth.size // 2
        steps = depth[depth > 0].astype(np.float64) / scale
        np.testing.assert_allclose(steps, np.rint(steps), rtol=0, atol=1e-3)
        assert 0.2 < float(np.median(depth[depth > 0])) < 2.0


def _copy(runs: dict, tmp_path: Path) -> Path:
    root = tmp_path / "ds"
    shutil.copytree(runs["a"][0], root)
    return root


def test_load_dataset_missing_rgb(runs: dict, tmp_path: Path) -> None:
    root = _copy(runs, tmp_path)
    missing = root / "rgb" / "000001.png"
    missing.unlink()
    with pytest.raises(DatasetError, match=re.escape(str(missing))):
        ds = load_dataset(root)
        for i in range(len(ds)):
            ds.frame(i)


def test_load_dataset_wrong_version(runs: dict, tmp_path: Path) -> None:
    root = _copy(runs, tmp_path)
    meta = json.loads((root / "dataset.json").read_text())
    meta["version"] = 99
    (root / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"dataset\.json.*'version'.*99"):
        load_dataset(root)


def test_load_dataset_missing_column(runs: dict, tmp_path: Path) -> None:
    root = _copy(runs, tmp_path)
    with open(root / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    with open(root / "frames.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, [c for c in rows[0] if c != "qw"], extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    with pytest.raises(DatasetError, match=r"frames\.csv.*'qw'"):
        load_dataset(root)


# --- waypoint files ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("x_m,y_m,z_m,label\n0,0,0.5,a\n", "header needs the columns x_m,y_m,z_m,qw,qx,qy,qz"),
        ("x_m,y_m,z_m,qw,qx,qy,qz\n# comment\n0,0,0.5,1,0,0,0\n0,0,abc,1,0,0,0\n", "waypoint 1 (data row 2)"),
        ("x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0.5,1,0,0,0\n0,0,0.5,1,1,0,0\n", "waypoint 1: quaternion"),
    ],
    ids=["header", "not-a-number", "non-unit-quaternion"],
)
def test_waypoint_file_errors(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "bad_waypoints.csv"
    path.write_text(text)
    with pytest.raises(WaypointFileError, match=re.escape(str(path)) + ".*" + re.escape(expected)):
        read_waypoint_file(path)


def test_waypoint_file_without_rows(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("x_m,y_m,z_m,qw,qx,qy,qz,label\n")
    with pytest.raises(WaypointFileError) as info:
        read_waypoint_file(path)
    assert str(path) in str(info.value) and "no waypoints" in str(info.value)


def test_waypoint_file_round_trip(tmp_path: Path) -> None:
    waypoints = _good(*GOOD_VIEWS)
    write_waypoint_file(tmp_path / "w.csv", waypoints)
    read = read_waypoint_file(tmp_path / "w.csv")
    assert [w.label for w in read] == [w.label for w in waypoints]
    for a, b in zip(read, waypoints, strict=True):
        np.testing.assert_allclose(a.T_base_flange, b.T_base_flange, rtol=0, atol=1e-12)


# --- previews and the printable board ---------------------------------------------------------------


def test_preview_images(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = _write_case(tmp_path / "case", _good(0, 9))
    out = tmp_path / "out"
    assert main(["simulate", "--out", str(out), "--scenario", str(scenario), "--quiet", "--preview"]) == 0
    stdout = capsys.readouterr().out
    for name in ("overview.png", "contact_sheet.png"):
        path = out / "preview" / name
        assert f"preview: {path}" in stdout
        image = cv2.imread(str(path))
        assert image is not None and image.size > 0 and float(image.std()) > 5.0
    assert cv2.imread(str(out / "preview" / "overview.png")).shape == (960, 1280, 3)
    assert len(load_dataset(out)) == 2


def test_board_png_and_pdf_at_true_scale(tmp_path: Path) -> None:
    board = json.loads((models_dir() / "boards" / "hec_8qr.json").read_text())
    width_m, height_m = board["size_m"]
    png = tmp_path / "board.png"
    assert main(["board", "--out", str(png), "--dpi", "300"]) == 0
    with Image.open(png) as image:
        # PNG stores whole pixels per metre (11811 for 300 dpi), which reads back as 299.9994 dpi.
        assert image.info["dpi"] == pytest.approx((300, 300), abs=1e-3)
        assert image.size == (round(width_m * 300 / 0.0254), round(height_m * 300 / 0.0254))
    pdf = tmp_path / "board.pdf"
    assert main(["board", "--out", str(pdf), "--dpi", "300"]) == 0
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF")
    box = re.search(rb"/MediaBox\s*\[\s*0\s+0\s+([\d.]+)\s+([\d.]+)\s*\]", data)
    assert box is not None
    # Page size in points (1/72 inch): the sheet at true scale, to within one 300 dpi pixel.
    page_m = [float(v) / 72 * 0.0254 for v in box.groups()]
    np.testing.assert_allclose(page_m, [width_m, height_m], rtol=0, atol=0.0254 / 300)


def test_the_first_compile_is_announced_until_numba_has_cached_every_pass(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A new install compiles the image-error passes on the first realistic view (15-20 s): simulate
    says so until numba's cache holds every compiled module."""
    from hec.sim import compiled

    cached = [
        m
        for m in compiled.COMPILED_MODULES
        if any((Path(compiled.__file__).parent / "__pycache__").glob(f"{m}.*.nbi"))
    ]
    monkeypatch.setattr(compiled, "COMPILED_MODULES", (*cached, "a_module_never_compiled"))
    assert "compiling the simulator's image and depth error passes" in compiled.first_compile_note()
    monkeypatch.setattr(compiled, "COMPILED_MODULES", tuple(cached))
    assert compiled.first_compile_note() is None

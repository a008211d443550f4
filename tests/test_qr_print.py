"""Boards printed by other generators: the symbols' masks, any payload, the causes of rejections,
and markers whose quiet zone the image border cuts."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import qrcode
from qrcode.util import MODE_8BIT_BYTE, QRData

from hec.cli import main
from hec.estimator.io.board_file import board_from_dict, board_to_dict, find_board, load_board
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.grading import grade_observations
from hec.estimator.observe.observations import dataset_depth_noise, observe_dataset, observe_frame
from hec.estimator.targets.board import BoardDefinition
from hec.estimator.targets.qr import DetectorSettings, QRDetector
from hec.estimator.targets.qr_symbol import SymbolSpec, read_format
from hec.estimator.targets.target import BoardDefinitionError
from tests.conftest import TEST_SEED


def _foreign_board_dict() -> dict:
    """hec_8qr's layout with payloads 'Landmark 1'..'Landmark 8' and every mask other than
    the qrcode package's choice."""
    d = board_to_dict(find_board("hec_8qr"))
    del d["payload_prefix"]
    d["name"] = "foreign-8qr"
    for m in d["markers"]:
        m["payload"] = f"Landmark {m['id'] + 1}"
        automatic = SymbolSpec(m["payload"], 1, "M").pinned().mask
        m["qr_mask"] = (automatic + 1 + m["id"] % 7) % 8
    return d


@pytest.fixture(scope="module")
def foreign(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    """The default scenario with the foreign board printed (its dataset's board.json states the masks)."""
    from hec.sim.scenario import scenario_from_dict
    from hec.sim.simulate import simulate

    root = tmp_path_factory.mktemp("foreign")
    (root / "printed.json").write_text(json.dumps(_foreign_board_dict()))
    scenario = scenario_from_dict({"board": {"definition": str(root / "printed.json")}})
    return load_dataset(simulate(scenario, root / "dataset", TEST_SEED, progress=False).out_dir)


def _without_masks(board: BoardDefinition) -> BoardDefinition:
    """The same board as a file that states no masks (an older file, or another team's board)."""
    return replace(board, marker_symbols={i: replace(s, mask=None) for i, s in board.marker_symbols.items()})


def _observe(dataset: Dataset, board: BoardDefinition, frames: range | None = None, **settings):
    detector = QRDetector(board, DetectorSettings(**settings))
    noise = dataset_depth_noise(dataset)
    return [observe_frame(i, dataset.frame(i), detector, noise) for i in frames or range(len(dataset))]


def _summary(dataset: Dataset, observations) -> dict:
    return grade_observations(observations, dataset.ground_truth, dataset.board, dataset.intrinsics).summary()


# --- the board definition --------------------------------------------------------------------------


def test_old_board_files_read_and_write_as_before() -> None:
    """A file without payloads or masks keeps the prefix-and-number payloads and the automatic
    mask, and writes back field for field (datasets' board.json stay byte-identical)."""
    path = Path(__file__).parents[1] / "models" / "boards" / "hec_8qr.json"
    raw = json.loads(path.read_text())
    board = load_board(path)
    assert board_to_dict(board) == {
        k: v for k, v in raw.items() if k not in ("description", "frame", "corner_order")
    }
    assert board.payload(3) == "HEC1/8QR/03" and board.marker_id_from_payload("HEC1/8QR/03") == 3
    assert board.marker_id_from_payload("HEC1/8QR/3") is None
    qr = qrcode.QRCode(version=1, error_correction=qrcode.constants.ERROR_CORRECT_M, border=0)
    qr.add_data("HEC1/8QR/03")
    qr.make(fit=False)
    np.testing.assert_array_equal(board.module_matrix(3), np.array(qr.get_matrix(), dtype=bool))


def test_a_board_file_maps_any_payload_and_mask() -> None:
    board = board_from_dict(_foreign_board_dict(), "foreign.json")
    assert board.marker_id_from_payload("Landmark 4") == 3
    assert board.marker_id_from_payload("Landmark 9") is None
    assert board.marker_id_from_payload("HEC1/8QR/03") is None
    for i in board.marker_ids:
        spec = board.symbol(i)
        qr = qrcode.QRCode(version=1, error_correction=0, border=0, mask_pattern=spec.mask)
        qr.add_data(spec.payload)
        qr.make(fit=False)
        np.testing.assert_array_equal(board.module_matrix(i), np.array(qr.get_matrix(), dtype=bool))
        assert spec.mask != replace(spec, mask=None).pinned().mask
    assert board_from_dict(board_to_dict(board)) == board


@pytest.mark.parametrize(
    "change, expected",
    [
        (lambda d: d["markers"][2].update(qr_mask=8), "markers[2].qr_mask must be 0-7"),
        (lambda d: d["markers"][1].update(payload="Landmark 1"), "two markers carry the same payload"),
        (lambda d: d["markers"][0].pop("payload"), "markers[0] has no 'payload'"),
        (
            lambda d: d["markers"][4].update(payload="x" * 20),
            "markers[4]: payload 'xxxxxxxxxxxxxxxxxxxx' does not",
        ),
        (lambda d: d["markers"][5].update(qr_error_correction="X"), "markers[5].qr_error_correction must be"),
    ],
)
def test_bad_symbol_fields_are_named(change, expected: str) -> None:
    d = _foreign_board_dict()
    change(d)
    with pytest.raises(BoardDefinitionError, match="foreign.json: ") as err:
        board_from_dict(d, "foreign.json")
    assert expected in str(err.value)


def test_format_modules_read_every_level_and_mask() -> None:
    """read_format recovers what qrcode wrote, also with 3 of the 30 format bits flipped."""
    rng = np.random.default_rng(0)
    for level in "LMQH":
        for mask in range(8):
            modules = SymbolSpec("Landmark 1", 2, level, mask).matrix().copy()
            assert read_format(modules) == (level, mask, 0)
            rows, cols = rng.choice([0, 1, 2, 3, 4, 5, 7], 3, replace=False), [8, 8, 8]
            modules[rows, cols] ^= True
            assert read_format(modules)[:2] == (level, mask)


def test_hec_board_writes_the_masks_it_printed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["board", "--out", str(tmp_path / "sheet.png")]) == 0
    assert f"wrote {tmp_path / 'sheet.json'}" in capsys.readouterr().out
    printed = load_board(tmp_path / "sheet.json")
    board = find_board("hec_8qr")
    for i in board.marker_ids:
        assert printed.symbol(i).mask is not None
        assert printed.symbol(i) == board.symbol(i).pinned()
        np.testing.assert_array_equal(printed.module_matrix(i), board.module_matrix(i))
    source = tmp_path / "mine.json"
    source.write_text(json.dumps(board_to_dict(board)))
    assert main(["board", "--board", str(source), "--out", str(tmp_path / "mine.pdf")]) == 2
    assert "choose --definition" in capsys.readouterr().err


# --- rendered boards printed by another generator --------------------------------------------------


def test_foreign_board_with_its_masks_stated(foreign: Dataset, default_dataset: Path) -> None:
    """Other masks and other payloads, stated in the board file: >= 99 % of the visible markers,
    corners as accurate as on hec's own board (same seed, same views)."""
    s = _summary(foreign, _observe(foreign, foreign.board))
    own = load_dataset(default_dataset)
    reference = _summary(own, observe_dataset(own))
    assert s["visible_markers"] >= 100
    assert s["detection_rate"] >= 0.99 and s["wrong_id"] == 0
    assert s["corner_rms_px"] <= 1.2 * reference["corner_rms_px"], (
        s["corner_rms_px"],
        reference["corner_rms_px"],
    )
    assert 0.7 <= s["corner_nees"] <= 1.5


def test_board_file_without_masks_follows_the_print(foreign: Dataset) -> None:
    """Without masks in the file the detector takes the one zxing read, says so once per marker
    in the whole dataset, and measures the same corners."""
    stated = _observe(foreign, foreign.board)
    followed = _observe(foreign, _without_masks(foreign.board))
    s = _summary(foreign, followed)
    assert s["detection_rate"] >= 0.99 and s["wrong_id"] == 0
    notes = [n for o in followed for n in o.notes]
    assert len(notes) == len(foreign.board.marker_ids)
    for i in foreign.board.marker_ids:
        automatic = replace(foreign.board.symbol(i), mask=None).pinned().mask
        assert sum(n.startswith(f"marker {i} is printed otherwise") for n in notes) == 1
        assert any(f"mask {foreign.board.symbol(i).mask} printed, {automatic} expected" in n for n in notes)
    for a, b in zip(stated, followed, strict=True):
        assert [m.marker_id for m in a.markers] == [m.marker_id for m in b.markers]
        for ma, mb in zip(a.markers, b.markers, strict=True):
            np.testing.assert_allclose(mb.corners_px, ma.corners_px, atol=1e-9)


def test_masks_read_from_the_format_modules_without_zxing(foreign: Dataset) -> None:
    """pyzbar reports no mask: the detector reads it from the symbol's format modules."""
    frames = range(0, len(foreign), 4)
    followed = _observe(foreign, _without_masks(foreign.board), frames, passes=("pyzbar@1", "pyzbar@2"))
    stated = _observe(foreign, foreign.board, frames, passes=("pyzbar@1", "pyzbar@2"))
    assert (
        sum(len(o.markers) for o in followed) == sum(len(o.markers) for o in stated) >= 0.9 * 8 * len(frames)
    )
    assert not [r.reason for o in followed for r in o.rejected if "printed" in r.reason]


def test_strict_detector_names_the_mask_that_differs(foreign: Dataset) -> None:
    obs = _observe(foreign, _without_masks(foreign.board), range(1), follow_printed_symbol=False)[0]
    assert obs.markers == []
    reasons = {r.marker_id: r.reason for r in obs.rejected}
    assert len(reasons) >= 6
    for i, reason in reasons.items():
        automatic = replace(foreign.board.symbol(i), mask=None).pinned().mask
        assert reason == (
            f"marker {i}: the printed code differs from the regenerated one: "
            f"mask {foreign.board.symbol(i).mask} printed, {automatic} expected"
        )


def test_payload_encoded_otherwise_is_named() -> None:
    """hec encodes 'HEC1/8QR/03' in alphanumeric mode; printed in byte mode (same text, same mask)
    the data modules differ, and the rejection says so instead of quoting a module percentage."""
    board = find_board("hec_8qr")
    spec = board.symbol(3).pinned()
    qr = qrcode.QRCode(version=1, error_correction=0, border=4, mask_pattern=spec.mask)
    qr.add_data(QRData(spec.payload.encode(), mode=MODE_8BIT_BYTE))
    qr.make(fit=False)
    s = 4
    texture = np.where(np.kron(np.array(qr.get_matrix(), bool), np.ones((s, s), bool)), 30, 200).astype(
        np.float32
    )
    H = cv2.getPerspectiveTransform(
        np.float32([[0, 0], [116, 0], [116, 116], [0, 116]]),
        np.float32([[240, 170], [352, 178], [346, 292], [236, 284]]),
    )
    image = cv2.warpPerspective(texture, H, (640, 480), flags=cv2.INTER_AREA, borderValue=200.0)
    found = QRDetector(board).detect(np.rint(image).astype(np.uint8))
    assert found.markers == []
    [reason] = [r.reason for r in found.rejected if r.marker_id == 3]
    assert f"differs from the regenerated one in its data: version 1-M, mask {spec.mask} on both" in reason
    assert reason.endswith("(the payload encoded otherwise, by another QR generator?)")


# --- the quiet zone cut by the image border ----------------------------------------------------------


def _leftmost(dataset: Dataset, frame: int):
    markers = QRDetector(dataset.board).detect(dataset.frame(frame).rgb).markers
    return min(markers, key=lambda m: m.corners_px[:, 0].min())


def test_marker_whose_quiet_zone_is_cut_is_measured(default_dataset: Path) -> None:
    """The image cropped half a module left of a marker's code: the marker is still measured, from
    the inside of its quiet zone, with the corners of the uncropped image."""
    dataset = load_dataset(default_dataset)
    marker = _leftmost(dataset, 0)
    module_px = np.linalg.norm(marker.corners_px[1] - marker.corners_px[0]) / dataset.board.modules
    cut = int(np.floor(marker.corners_px[:, 0].min() - 0.5 * module_px))
    found = QRDetector(dataset.board).detect(np.ascontiguousarray(dataset.frame(0).rgb[:, cut:]))
    [again] = [m for m in found.markers if m.marker_id == marker.marker_id]
    np.testing.assert_allclose(again.corners_px + [cut, 0], marker.corners_px, atol=0.02)


def test_undecoded_marker_with_a_cut_quiet_zone_is_reported(default_dataset: Path) -> None:
    """If no decoder reads such a marker, its rejection says its quiet zone leaves the image."""
    dataset = load_dataset(default_dataset)
    marker = _leftmost(dataset, 0)
    module_px = np.linalg.norm(marker.corners_px[1] - marker.corners_px[0]) / dataset.board.modules
    cut = int(np.floor(marker.corners_px[:, 0].min() - 0.5 * module_px))
    rgb = dataset.frame(0).rgb.copy()
    cv2.fillConvexPoly(rgb, np.rint(marker.corners_px).astype(np.int32), (128, 128, 128))  # unreadable
    found = QRDetector(dataset.board).detect(np.ascontiguousarray(rgb[:, cut:]))
    [reason] = [r.reason for r in found.rejected if r.marker_id == marker.marker_id]
    assert "no pass decoded it" in reason and reason.endswith("its quiet zone leaves the image")

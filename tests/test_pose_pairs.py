"""pose_pairs.json: what is written reads back, and bad files name the file and the field."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.transforms import make_transform
from hec.estimator.observe.pose_pairs import PosePair, PosePairError, read_pose_pairs, write_pose_pairs


def _pose(rng: np.random.Generator) -> np.ndarray:
    return make_transform(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))


def test_pairs_read_back_as_written(tmp_path):
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    pairs = [
        PosePair(0, _pose(rng), _pose(rng), A @ A.T + np.eye(6)),
        PosePair(3, _pose(rng), _pose(rng)),
    ]
    path = write_pose_pairs(tmp_path / "pose_pairs.json", pairs, {"layout": "easy_handeye2"})
    read, source = read_pose_pairs(path)
    assert source == {"layout": "easy_handeye2"}
    assert [p.frame for p in read] == [0, 3]
    for a, b in zip(pairs, read, strict=True):
        np.testing.assert_array_equal(a.T_base_flange, b.T_base_flange)
        np.testing.assert_array_equal(a.T_cam_board, b.T_cam_board)
    np.testing.assert_array_equal(read[0].covariance, pairs[0].covariance)
    assert read[1].covariance is None


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(format="other"), "expected 'format': 'hec-pose-pairs'"),
        (lambda d: d.update(pairs=[]), "field 'pairs' should be a non-empty list"),
        (lambda d: d["pairs"][0].update(frame=-1), "pairs[0].frame: expected an integer >= 0"),
        (lambda d: d["pairs"][0]["T_cam_board"][0].__setitem__(0, 2.0), "pairs[0].T_cam_board: not a rigid"),
        (
            lambda d: d["pairs"][0].update(T_base_flange=[[1, 0], [0, 1]]),
            "pairs[0].T_base_flange: expected a 4x4",
        ),
        (
            lambda d: d["pairs"][0].update(covariance=np.diag([1, 1, 1, 1, 1, -1.0]).tolist()),
            "positive definite",
        ),
        (lambda d: d["pairs"].append(dict(d["pairs"][0])), "two pairs have the same 'frame'"),
    ],
)
def test_bad_files_name_the_file_and_the_field(tmp_path, change, message):
    rng = np.random.default_rng(1)
    path = write_pose_pairs(tmp_path / "pose_pairs.json", [PosePair(0, _pose(rng), _pose(rng))], {})
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    with pytest.raises(PosePairError, match="pose_pairs.json") as error:
        read_pose_pairs(path)
    assert message in str(error.value)

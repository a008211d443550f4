"""A self-calibration finding is advice only where it holds: significant, stable without the depth
scale and the lens term when the data do not need them, and not traded against another group the data
need; otherwise "cannot tell apart" with what would separate them."""

from __future__ import annotations

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.solve.finding_check import check_findings
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.noise_levels import NoiseLevels
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene

NAMES = ("board_scale_x", "board_scale_y", "depth_scale", "depth_offset_m")


def _learned(theta: list[float], sigma: list[float], correlation: float) -> LearnedNoise:
    """A learning pass that kept the board's print scale and the depth's bias with these corrections
    and sigmas (NAMES order), board_scale_x and depth_scale correlated as given."""
    C = np.diag(np.square(sigma))
    C[0, 2] = C[2, 0] = correlation * sigma[0] * sigma[2]
    levels = NoiseLevels(1.0, 1.0, RobotPoseNoise())
    return LearnedNoise(
        levels,
        levels,
        {},
        {},
        1.0,
        1,
        HandEyeState(make_transform(np.eye(3), np.zeros(3)), T_base_board=np.eye(4)),
        set(),
        [],
        theta=np.array(theta),
        theta_covariance=C,
        theta_names=NAMES,
        groups_kept=("board_scale", "depth_bias"),
    )


def _problem():
    rng = np.random.default_rng(0)
    observations = scene(random_mount(rng), rng, views=4)
    return build_problem(observations, BOARD, INTRINSICS)


def test_a_significant_print_scale_the_data_need_alone_is_advice() -> None:
    checks = check_findings(_problem(), _learned([0.004, 0.0, 0.001, 0.0], [0.001, 0.001, 0.002, 0.001], 0.3))
    assert checks["board_scale"].significant and checks["board_scale"].holds, checks
    assert not checks["depth_bias"].significant


def test_a_print_scale_that_fades_without_the_depth_scale_cannot_be_told_apart() -> None:
    """The depth scale (3 sigma: the data do not need it) carries 85 % of the print scale: without it
    the print scale is 2.8 sigma."""
    checks = check_findings(
        _problem(), _learned([0.004, 0.0, 0.006, 0.0], [0.001, 0.001, 0.002, 0.001], 0.85)
    )
    board = checks["board_scale"]
    assert board.significant and not board.stable and not board.holds, board
    words = board.cannot_tell()
    assert "cannot tell the board's print scale apart from the depth's scale and offset" in words, words
    assert "views nearer to and farther from the board would separate them" in words, words


def test_two_needed_groups_trading_one_for_the_other_are_neither_advice() -> None:
    checks = check_findings(_problem(), _learned([0.012, 0.0, 0.02, 0.0], [0.001, 0.001, 0.001, 0.001], 0.95))
    assert checks["board_scale"].significant and checks["depth_bias"].significant
    assert not checks["board_scale"].holds and not checks["depth_bias"].holds
    assert "(their estimates are 95% correlated)" in checks["board_scale"].cannot_tell()


def test_a_finding_beside_a_needed_group_with_no_material_correction_is_advice() -> None:
    """The depth's scale is needed (4 sigma) but immaterial (0.04 %, below the 0.1 % worth
    reporting) and 95 % correlated with a print scale 40 sigma off: it is no rival, and the print
    scale's marginal sigma (which carries the trade) says how well it is known."""
    checks = check_findings(
        _problem(), _learned([0.004, 0.0, 0.0004, 0.0], [0.0001, 0.0001, 0.0001, 0.001], 0.95)
    )
    assert not checks["depth_bias"].significant
    assert checks["board_scale"].significant and checks["board_scale"].holds, checks


def test_a_correction_that_only_just_reaches_a_noteworthy_size_is_no_finding() -> None:
    """A print scale 0.12 % +- 0.03 % off: 4 sigma, beyond the 0.1 % worth reporting, but not with
    one sigma taken off; 0.14 % +- 0.03 % is."""
    sigma = [0.0003, 0.0003, 0.002, 0.001]
    assert not check_findings(_problem(), _learned([0.0012, 0.0, 0.0, 0.0], sigma, 0.0))[
        "board_scale"
    ].significant
    assert check_findings(_problem(), _learned([0.0014, 0.0, 0.0, 0.0], sigma, 0.0))[
        "board_scale"
    ].significant

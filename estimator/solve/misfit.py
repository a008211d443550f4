"""Does a calibration fit its data? Its RMS pixel residual against the data's noise (data_noise_px:
what each view's own board pose and the declared arm noise leave), for every method, OpenCV's too.
A result more than MISFIT_RATIO times the noise does not fit: it says so and names the frames that
disagree most, by where each puts the board in the base frame with the result's mount (a frame
whose image and robot pose do not belong together puts it farthest from the others)."""

from __future__ import annotations

import cv2
import numpy as np

from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.initialise import board_pose_pnp
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem, FrameMeasurements

# A result whose RMS residual is above this many times the data's noise does not fit its data (a
# realistic cell's model errors leave up to about 4 times; a frame paired with another's image 100+).
MISFIT_RATIO = 10.0
# The frames named as disagreeing most.
FRAMES_NAMED = 3


def data_noise_px(problem: CalibrationProblem) -> float:
    """The RMS pixel residual the data's noise alone leaves (pixels): each frame's own board pose
    (PnP) residual, with the declared robot pose noise seen at the board's distance added in
    quadrature (focal length x (translation sigma / distance + rotation sigma))."""
    corners = board_residual_px(problem, np.ones(3))
    focal = float(np.mean(np.diag(problem.intrinsics.K)[:2]))
    distance = float(np.median([_board_distance_m(problem, f) for f in problem.frames]))
    noise = problem.robot_noise
    robot = focal * (noise.translation_sigma_m / max(distance, 1e-3) + noise.rotation_sigma_rad)
    return float(np.hypot(corners, robot))


def _board_distance_m(problem: CalibrationProblem, frame: FrameMeasurements) -> float:
    try:
        return float(np.linalg.norm(board_pose_pnp(problem, frame)[:3, 3]))
    except CalibrationInputError:
        return float("nan")


def board_residual_px(problem: CalibrationProblem, mirror: np.ndarray) -> float:
    """RMS pixel residual of each frame's PnP board pose, the markers' centres scaled by mirror (3,)."""
    K, dist = problem.intrinsics.K, np.array(problem.intrinsics.dist, dtype=np.float64)
    squared, count = 0.0, 0
    for frame in problem.frames:
        points = []
        for m in frame.markers:
            center = m.corners_board.mean(axis=0)
            points.append(m.corners_board - center + mirror * center)
        object_points = np.concatenate(points)
        image_points = np.concatenate([m.corners_px for m in frame.markers])
        ok, rvec, tvec = cv2.solvePnP(object_points, image_points, K, dist, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            return float("inf")
        projected = cv2.projectPoints(object_points, rvec, tvec, K, dist)[0].reshape(-1, 2)
        squared += float(np.sum((projected - image_points) ** 2))
        count += len(image_points)
    return float(np.sqrt(squared / max(count, 1)))


def declared_corner_sigma_px(problem: CalibrationProblem) -> float:
    """The RMS 1-sigma of a corner's pixel position the problem's noise model declares (pixels)."""
    variances = []
    for frame in problem.frames:
        for m in frame.markers:
            W = m.whitening[: m.pixel_rows, : 2 * len(m.corners_px)]
            variances.append(np.mean(np.diag(np.linalg.pinv(W.T @ W))))
    return float(np.sqrt(np.mean(variances))) if variances else float("nan")


def disagreeing_frames(problem: CalibrationProblem, T_flange_cam: np.ndarray) -> list[tuple[int, float]]:
    """(frame, metres) of the FRAMES_NAMED frames that put the board farthest from the median of
    where the frames put it in the base frame (T_base_flange @ T_flange_cam @ its PnP board pose)."""
    where = {}
    for frame in problem.frames:
        try:
            where[frame.frame] = (frame.T_base_flange @ T_flange_cam @ board_pose_pnp(problem, frame))[:3, 3]
        except CalibrationInputError:
            continue
    if not where:
        return []
    median = np.median(np.array(list(where.values())), axis=0)
    off = {f: float(np.linalg.norm(t - median)) for f, t in where.items()}
    return sorted(off.items(), key=lambda item: -item[1])[:FRAMES_NAMED]


def misfit_warning(problem: CalibrationProblem, result: Calibration) -> str | None:
    """The warning of a result that does not fit its data (module doc), or None when it fits."""
    rms = result.residual_rms_px
    noise = data_noise_px(problem)
    if not (np.isfinite(rms) and np.isfinite(noise)) or rms <= MISFIT_RATIO * max(noise, 1e-9):
        return None
    frames = ", ".join(
        f"frame {f} ({1e3 * m:.0f} mm)" for f, m in disagreeing_frames(problem, result.T_flange_cam)
    )
    return (
        f"{result.method}'s result does not fit its data: RMS residual {rms:.3g} px, {rms / noise:.0f} times "
        f"the data's noise ({noise:.2g} px: each view's own board pose and the declared arm noise); the "
        f"frames that disagree most, by how far from the others each puts the board: {frames}; check that "
        "each frame's image and robot pose belong together, the pose convention, the board file and the "
        "intrinsics; do not use this result"
    )

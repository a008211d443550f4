"""Self-calibration: the camera's intrinsics, its radial distortion, the board's print scale and
the depth's scale and offset estimated with the mount, for when the model the dataset declares
does not fit.

The nuisance parameters theta (NUISANCE) are corrections to what the problem declares:
focal lengths and principal point (pixels), the radial distortion k1, k2 (added to the declared
coefficients), the printed board's scale along its x and y (log scales, so about the
fractions: corners scaled by exp(theta) about the board frame's origin), the depth bias
(CalibrationProblem.depth_bias: measured depth = exp(depth_scale) (z + depth_offset_m), z the
true depth) and the board's sag out of its plane (CalibrationProblem.board_bend_m: a sheet on
foam sags by a millimetre; unmodelled, self-calibration bent the focal length and the
distortion instead). Each has a Gaussian prior (PRIOR_SIGMA: factory intrinsics are a few tenths of a
percent and a few pixels off, a print a few tenths of a percent, a stereo camera's depth a
percent or two and a few millimetres, a sag 2 mm), so theta stays determined when the views do not separate
it from the mount. From views at one distance a print scale and a depth scale look alike (either
explains a board that looks nearer in the image than in the depth): the priors then share the
difference out, and the covariance of T_flange_cam carries what that leaves unknown; views at two
distances separate them. The batch objective gains theta as parameters (their Jacobian analytic,
from predict_frame) and its prior rows; the noise learning runs on it when the declared model
fits badly, and every method then solves the adjusted problem.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from estimator.solve.batch import BatchObjective
from estimator.solve.measurement_model import predict_frame
from estimator.solve.problem import CalibrationProblem

NUISANCE = (
    "fx_px",
    "fy_px",
    "cx_px",
    "cy_px",
    "k1",
    "k2",
    "board_scale_x",
    "board_scale_y",
    "depth_scale",
    "depth_offset_m",
    "board_bend_x_m",
    "board_bend_y_m",
)
# Prior sigmas: focal lengths as a fraction of the declared one, the rest as they are.
FOCAL_PRIOR_FRACTION = 0.05
PRIOR_SIGMA = {
    "cx_px": 20.0,
    "cy_px": 20.0,
    "k1": 0.5,
    "k2": 0.5,
    "board_scale_x": 0.03,
    "board_scale_y": 0.03,
    "depth_scale": 0.02,
    "depth_offset_m": 0.005,
    "board_bend_x_m": 0.002,
    "board_bend_y_m": 0.002,
}


def prior_sigma(problem: CalibrationProblem) -> np.ndarray:
    """(len(NUISANCE),) prior sigmas of theta for this problem's camera."""
    k = problem.intrinsics
    focal = {"fx_px": FOCAL_PRIOR_FRACTION * k.fx, "fy_px": FOCAL_PRIOR_FRACTION * k.fy}
    return np.array([{**PRIOR_SIGMA, **focal}[name] for name in NUISANCE])


def adjusted_problem(problem: CalibrationProblem, theta: np.ndarray) -> CalibrationProblem:
    """The problem with the camera, the board, the depth bias and the board's bend corrected by
    theta (NUISANCE order; the depth bias and the bend replaced: the declared problem has none)."""
    k = problem.intrinsics
    dist = list(k.dist) + [0.0] * (5 - len(k.dist))
    dist[0] += float(theta[4])
    dist[1] += float(theta[5])
    intrinsics = replace(
        k,
        fx=k.fx + float(theta[0]),
        fy=k.fy + float(theta[1]),
        cx=k.cx + float(theta[2]),
        cy=k.cy + float(theta[3]),
        dist=tuple(dist),
    )
    scale = np.array([np.exp(theta[6]), np.exp(theta[7]), 1.0])
    frames = [
        replace(f, markers=[replace(m, corners_board=m.corners_board * scale) for m in f.markers])
        for f in problem.frames
    ]
    depth_bias = (float(theta[8]), float(theta[9]))
    bend = (float(theta[10]), float(theta[11]))
    return replace(problem, intrinsics=intrinsics, frames=frames, depth_bias=depth_bias, board_bend_m=bend)


class SelfCalibrationObjective:
    """The batch objective over params = [BatchObjective's params, theta (NUISANCE)], with theta's
    prior rows last. base: the problem as declared (its whitening and robot noise as learned)."""

    def __init__(
        self, base: CalibrationProblem, make: Callable[[CalibrationProblem], BatchObjective]
    ) -> None:
        self.base = base
        self.make = make  # problem -> BatchObjective
        self.sqrt_info = 1.0 / prior_sigma(base)
        self.inner = make(base)
        self._key, self._inner_at = None, self.inner
        self.n = self.inner.n
        self.prior = self.inner.prior
        self.with_robot = self.inner.with_robot

    @property
    def size(self) -> int:
        return self.inner.size + len(NUISANCE)

    def _objective(self, theta: np.ndarray) -> BatchObjective:
        key = theta.tobytes()
        if key != self._key:
            self._key, self._inner_at = key, self.make(adjusted_problem(self.base, theta))
        return self._inner_at

    def residuals(self, params: np.ndarray) -> np.ndarray:
        theta = params[self.inner.size :]
        inner = self._objective(theta).residuals(params[: self.inner.size])
        return np.concatenate([inner, self.sqrt_info * theta])

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        """The batch Jacobian, theta's columns (analytic: predict_frame's camera Jacobian) and
        theta's prior rows."""
        x, theta = params[: self.inner.size], params[self.inner.size :]
        objective = self._objective(theta)
        state = objective.start.plus(x[: objective.n])
        blocks = [np.zeros((objective.n + (6 if objective.prior is not None else 0), len(theta)))]
        for i, frame in enumerate(objective.problem.frames):
            delta = objective._delta(x, i)
            pred = predict_frame(objective.problem, state, frame, delta, camera_jacobian=True)
            blocks.append(pred.J_camera)
            if objective.with_robot:
                blocks.append(np.zeros((6, len(theta))))
        top = np.hstack([objective.jacobian(x), np.concatenate(blocks)])
        bottom = np.hstack([np.zeros((len(theta), self.inner.size)), np.diag(self.sqrt_info)])
        return np.vstack([top, bottom])

    def frame_residuals(self, params: np.ndarray) -> list[np.ndarray]:
        theta = params[self.inner.size :]
        return self._objective(theta).frame_residuals(params[: self.inner.size])

"""Every calibration method behind one call, with the observability check added to each result."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimator.observe.observations import FrameObservations
from estimator.solve.baselines import OPENCV_METHODS, opencv_calibrate
from estimator.solve.batch import batch
from estimator.solve.calibration import Calibration, MethodOptions
from estimator.solve.filters import run_filter
from estimator.solve.measurement_model import HandEyeState
from estimator.solve.observability import observability
from estimator.solve.problem import CalibrationProblem
from estimator.solve.seed_ekf import seed_ekf
from estimator.solve.ukf import ukf

Method = Callable[[CalibrationProblem, MethodOptions, list[FrameObservations]], Calibration]

METHODS: dict[str, Method] = {
    "seed-ekf": seed_ekf,
    "ekf": lambda problem, options, _: run_filter(problem, options, iterated=False),
    "iekf": lambda problem, options, _: run_filter(problem, options, iterated=True),
    "ukf": lambda problem, options, _: ukf(problem, options),
    "batch": lambda problem, options, _: batch(problem, options),
    **{
        name: (lambda problem, options, _, name=name: opencv_calibrate(problem, options, name))
        for name in OPENCV_METHODS
    },
}
DEFAULT_METHOD = "ekf"


def run_method(
    name: str, problem: CalibrationProblem, options: MethodOptions, observations: list[FrameObservations]
) -> Calibration:
    """Run one method; its result carries diagnostics['observability'] and the warnings it raises."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)} or 'all'")
    result = METHODS[name](problem, options, observations)
    if result.T_base_board is not None:
        state = HandEyeState(result.T_flange_cam, T_base_board=result.T_base_board)
    else:
        corners = np.concatenate([result.landmarks_base[i] for i in problem.marker_ids])
        state = HandEyeState(result.T_flange_cam, landmarks_base=corners)
    report = observability(problem, state)
    result.diagnostics["observability"] = report
    result.warnings.extend(w for w in report.warnings if w not in result.warnings)
    return result

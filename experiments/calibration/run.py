"""Running calibration methods on one problem: the fail-fast check that the poses fit the images at
all, the noise learned once and shared, each method's leave-one-frame-out folds, the arm's findings
and the pick error (what `hec calibrate` and hec.api both run)."""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
from tqdm import tqdm

from hec.calibration.arm_findings import joint_order_warning, joint_zero_warning
from hec.calibration.loo import (
    BUDGET_S,
    LOO_DECLARED_KEY,
    LooModel,
    add_cross_validation,
    declared_model,
    self_calibrated_model,
)
from hec.calibration.report import MethodFailure, Result, add_pick_error
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.transforms import invert
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import needs_learned_noise, run_method
from hec.estimator.solve.noise_learning import LearnedNoise, learn_noise
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem

# The closed forms the poses are checked with before any estimation, in order (each takes
# milliseconds); Park alone finds no mount on some data the others fit.
CHECK_METHODS = ("opencv-park", "opencv-tsai", "opencv-horaud")


def run_methods(
    names: list[str],
    problem: CalibrationProblem,
    options: MethodOptions,
    observations: list[FrameObservations],
    quiet: bool = True,
    loo: bool = False,
    loo_budget_s: float | None = BUDGET_S,
) -> list[Result]:
    """Each method on the same problem. With several, a CalibrationInputError becomes a MethodFailure;
    with one, it is raised. loo: cross-validate each result whose folds fit in loo_budget_s seconds
    (None: any), hec.calibration.loo: one method in the model it ran with, several in the
    self-calibrated and the declared model alike; the others say why not."""
    results: list[Result] = []
    learned = None  # learned once, shared by the methods that model the noise
    order_warning = joint_order_warning(problem)
    if loo and len(names) > 1 and options.learn_noise:
        try:
            learned = _learn_noise(problem, options, quiet)
        except CalibrationInputError:
            pass  # each method that needs it fails with the reason
    bar = tqdm(names, desc="calibrate", unit="method", disable=quiet or len(names) == 1, file=sys.stderr)
    for name in bar:
        bar.set_postfix_str(name)
        try:
            if learned is None and needs_learned_noise(name, options):
                learned = _learn_noise(problem, options, quiet)
            cal = run_method(name, problem, options, observations, learned)
        except CalibrationInputError as exc:
            if len(names) == 1:
                raise
            results.append(MethodFailure(name, str(exc)))
            continue
        models = _loo_models(name, len(names) > 1, problem, options, learned) if loo else []
        for model in models or [declared_model(problem, options)]:
            add_cross_validation(cal, name, model, observations, loo, loo_budget_s, quiet)
        if needs_learned_noise(name, options):  # the methods that self-calibrate the arm
            arm = [order_warning, joint_zero_warning(cal.diagnostics.get("noise"))]
            cal.warnings.extend(w for w in arm if w is not None and w not in cal.warnings)
        add_pick_error(cal, problem)
        results.append(cal)
    return results


def _learn_noise(problem: CalibrationProblem, options: MethodOptions, quiet: bool) -> LearnedNoise:
    """learn_noise, saying what it does and how long it took unless quiet (it takes seconds)."""
    if not quiet:
        print(
            "calibrate: learning the noise from the data (and what the camera, board and arm need)",
            file=sys.stderr,
        )
    start = time.perf_counter()
    learned = learn_noise(problem, options)
    if not quiet:
        groups = ", ".join(g.replace("_", " ") for g in learned.groups_kept) or "nothing"
        print(
            f"calibrate: learned in {time.perf_counter() - start:.1f} s; self-calibrated: {groups}",
            file=sys.stderr,
        )
    return learned


def _loo_models(
    name: str,
    several: bool,
    problem: CalibrationProblem,
    options: MethodOptions,
    learned: LearnedNoise | None,
) -> list[LooModel]:
    """The models a method is cross-validated in: with several methods, the self-calibrated one (when
    the noise was learned) and the declared one, alike for all; alone, the one it ran with."""
    if learned is not None and (several or needs_learned_noise(name, options)):
        declared = [declared_model(problem, options, LOO_DECLARED_KEY)] if several else []
        return [self_calibrated_model(problem, options, learned), *declared]
    return [declared_model(problem, options)]


SETUP_WORDS = {
    EYE_IN_HAND: "the camera on the flange, the board fixed",
    EYE_TO_HAND: "the camera fixed in the cell, the board on the flange",
}


def _other_setup_fits(problem: CalibrationProblem) -> str | None:
    """The other set-up's name when OpenCV's Park method fits the frames in it (each flange pose
    inverted: hec.estimator.solve.setup_roles) within MAX_CORNER_RMS_PX, else None."""
    from hec.estimator.solve.baselines import opencv_calibrate
    from hec.estimator.solve.methods import MAX_CORNER_RMS_PX

    other = EYE_TO_HAND if problem.setup == EYE_IN_HAND else EYE_IN_HAND
    frames = [replace(f, T_base_flange=invert(f.T_base_flange), joints=None) for f in problem.frames]
    swapped = replace(problem, frames=frames, setup=other, kinematics=None)
    try:
        fits = opencv_calibrate(swapped, MethodOptions(), "opencv-park").residual_rms_px < MAX_CORNER_RMS_PX
    except CalibrationInputError:
        return None
    return other if fits else None


def check_poses_fit(dataset: Dataset, problem: CalibrationProblem) -> None:
    """Fail in seconds, before any estimation, when the robot poses do not fit the images at any mount:
    the best of OpenCV's closed forms (CHECK_METHODS, milliseconds each) leaves MAX_CORNER_RMS_PX or
    more, or none of them finds a mount at all. The error says why: the other set-up when the poses
    fit it (an eye-to-hand dataset read as eye-in-hand, or the other way round), else the convention
    check of an imported dataset's pose numbers (hec.estimator.io.convention_check)."""
    from hec.estimator.solve.baselines import opencv_calibrate
    from hec.estimator.solve.initialise import MIN_AXIS_SPREAD, rotation_spread
    from hec.estimator.solve.methods import MAX_CORNER_RMS_PX

    if rotation_spread([f.T_base_flange for f in problem.frames])[1] < MIN_AXIS_SPREAD:
        return  # too little rotation to tell: each method says so itself
    solved = []
    for method in CHECK_METHODS:
        try:
            solved.append(opencv_calibrate(problem, MethodOptions(), method))
        except CalibrationInputError:
            continue  # no solution from this closed form: the next may find one
        if solved[-1].residual_rms_px < MAX_CORNER_RMS_PX:
            return
    from hec.estimator.io.convention_check import check_pose_convention, px_text

    record = dataset.metadata.get("provenance") or {}
    if "pose_values" in record:
        from hec.estimator.io.pose_file import PoseConvention

        stated = PoseConvention(**record["pose_convention"])
        why = check_pose_convention(problem, np.array(record["pose_values"]), stated).message
    else:
        why = "check the pairing of images and poses, the pose convention, the board file and the intrinsics"
    other = _other_setup_fits(problem)
    if other is not None:  # inverted poses and the other set-up are the same model: name both
        inverted = why if "pose_values" in record else "T_flange_base read as T_base_flange"
        why = (
            f"they fit with every pose inverted: either they are inverted ({inverted}), or the cell is "
            f'{other} ({SETUP_WORDS[other]}): then record "setup": "{other}" in '
            f"{dataset.root / 'dataset.json'} (hec import --setup {other})"
        )
    best = min(solved, key=lambda c: c.residual_rms_px, default=None)
    best_text = f"none of {', '.join(CHECK_METHODS)} finds a mount"
    if best is not None:
        from hec.estimator.solve.misfit import disagreeing_frames

        best_text = f"the best closed-form mount leaves {px_text(best.residual_rms_px)} RMS"
        frames = ", ".join(
            f"frame {f} ({1e3 * m:.0f} mm)" for f, m in disagreeing_frames(problem, best.T_flange_cam)
        )
        why += f"; the frames that disagree most, by how far from the others each puts the board: {frames}"
    raise CalibrationInputError(
        f"the robot poses do not fit the images at any mount ({best_text}; {MAX_CORNER_RMS_PX:.0f} px RMS is "
        f"the most any model explains); {why}"
    )


def without_depth(observations: list[FrameObservations]) -> list[FrameObservations]:
    """Copies of the observations with every marker's depth removed (--no-depth), so that methods
    which read depth from the raw observations (seed-ekf) see none either."""
    gone = {"depth_m": None, "depth_cov": None, "points_cam": None, "points_cov": None}
    return [
        replace(o, markers=[replace(m, **gone, depth_note="depth not used (--no-depth)") for m in o.markers])
        for o in observations
    ]

"""Which pose convention fits the data: the common mistakes tried on imported robot poses.

Most wrong hand-eye results come from reading the robot's poses in the wrong convention: poses
inverted (flange-to-base for base-to-flange), a rotation vector read as Euler angles or the wrong
Euler order, degrees for radians, millimetres for metres, quaternions the other way round. Given
the numbers of a pose file and the convention they were read with, the check reads them in each
mistaken convention (alternative_conventions), calibrates each with OpenCV's Park method on the
problem's detected board (cheap, no noise model) and compares the RMS pixel residual with the
data's noise (data_noise_px: what the corners and the declared arm noise alone leave). A reading is
named only when it fits near that noise (within NOISE_RATIO of it): the stated one, or a mistake
that also leaves at most MISTAKE_RATIO of the stated one's residual. When none does, the report says
so with the residuals and what to check, never a fix. The same trials pair each image with its
neighbour's pose (a pose off by one). Motion that cannot tell the readings apart (translation only,
or rotation about one axis) is reported as "cannot check".

The same is done for the other common mistakes: pose pairs with the robot or the tracking poses
inverted, or both (check_pose_pair_directions); a board file whose marker layout is mirrored
(check_board_layout). The joints' checks are in hec.estimator.io.joint_check.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.transforms import invert
from hec.estimator.io.pose_file import EULER_SEQUENCES, PoseConvention, PoseFileError, poses_from_values
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.baselines import opencv_calibrate
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.misfit import board_residual_px, data_noise_px, declared_corner_sigma_px
from hec.estimator.solve.pose_pair_methods import PAIR_NOISE_FREE, PosePairModel, opencv_pose_pairs
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem
from hec.estimator.solve.setup_roles import model_pose

# A mistaken convention is named when it leaves at most this fraction of the stated one's residual.
MISTAKE_RATIO = 0.3
# ... and any reading only when its residual is at most this many times the data's noise.
NOISE_RATIO = 3.0
# Views whose rotations from one another are all under this (degrees) cannot tell readings apart, nor
# views whose rotation axes all lie within AXIS_SPREAD_DEG of one line.
MIN_ROTATION_DEG = 2.0
AXIS_SPREAD_DEG = 3.0
# Poses shifted against the images by these many frames (+1: each image has the next image's pose).
SHIFTS = (1, -1)
# Residuals above this (pixels) are shown as "over" it: their digits mean nothing.
LARGEST_SHOWN_PX = 1e4
# Which way a pose pair's board pose maps: camera-to-target is T_cam_board (easy_handeye2's tracking).
TRACKING_DIRECTIONS = ("camera-to-target", "target-to-camera")
_OPTION = {
    "rotation": "--rotation",
    "angle_unit": "--angle-unit",
    "length_unit": "--length-unit",
    "direction": "--pose-direction",
}


@dataclass(frozen=True)
class ConventionTrial:
    """One reading of the poses: the mistake in plain words ("" for the stated convention), its
    convention, the RMS pixel residual of a Park calibration with it (inf when Park finds no
    solution), the convention's fields that differ from the stated one and the pairing shift (0: as
    paired; +1: each image read with the next image's pose)."""

    mistake: str
    convention: PoseConvention
    residual_px: float
    changed_fields: tuple[str, ...] = ()
    shift: int = 0

    @property
    def option(self) -> str:
        """The options that select this convention, for example '--pose-direction flange-to-base'."""
        return " ".join(
            f"{_OPTION[k]} {v}" for k, v in self.convention.to_dict().items() if k in self.changed_fields
        )

    @property
    def fix(self) -> str:
        """What to do about it: pass the options, or for a shift check the pairing."""
        if self.shift:
            return "check the pairing of images and poses (a pose row missing or extra at the start?)"
        return f"pass {self.option}"

    @property
    def residual_text(self) -> str:
        return px_text(self.residual_px)


def px_text(residual_px: float) -> str:
    """A pixel residual in words: '3.42 px', 'over 10000 px' (points behind the camera, say), or
    'no Park solution' for inf."""
    if not np.isfinite(residual_px):
        return "no Park solution"
    return f"{residual_px:.3g} px" if residual_px < LARGEST_SHOWN_PX else f"over {LARGEST_SHOWN_PX:.0f} px"


@dataclass(frozen=True)
class ConventionReport:
    """The stated convention's trial, every mistake's, the one that fits (or None), the data's noise
    (pixels RMS, data_noise_px) and, when the motion cannot tell readings apart, why (else None)."""

    stated: ConventionTrial
    trials: list[ConventionTrial]
    fits: ConventionTrial | None
    noise_px: float
    cannot_check: str | None = None

    @property
    def stated_fits(self) -> bool:
        """The stated reading fits near the data's noise and no mistake fits better."""
        return self.cannot_check is None and self.fits is None and self._near_noise(self.stated)

    def _near_noise(self, trial: ConventionTrial) -> bool:
        return trial.residual_px <= NOISE_RATIO * self.noise_px

    @property
    def message(self) -> str:
        noise = f"the data's noise {self.noise_px:.2g} px"
        if self.cannot_check is not None:
            return f"cannot check the pose convention: {self.cannot_check}"
        if self.fits is not None:
            change = (
                f"the residual drops from {self.stated.residual_text} to {self.fits.residual_text}"
                if np.isfinite(self.stated.residual_px)
                else f"as stated Park finds no mount, read so the residual is {self.fits.residual_text}"
            )
            return f"the robot poses look like {self.fits.mistake}: {change} ({noise}); {self.fits.fix}"
        if self.stated_fits:
            return (
                f"the robot poses fit the stated convention ({self.stated.residual_text} RMS residual, "
                f"{noise}); none of the common mistakes fits better"
            )
        best = min(self.trials, key=lambda t: t.residual_px)
        check = (
            "check the pairing of images and poses, the time sync of poses and images, the camera's "
            "intrinsics and the arm's accuracy"
        )
        if self.stated.residual_px < MISTAKE_RATIO * best.residual_px:
            return (
                f"the stated convention fits far better than any common mistake ({self.stated.residual_text} "
                f"RMS residual; the next, {best.mistake}, {best.residual_text}) but not near {noise}: {check}"
            )
        return (
            f"no reading of the poses fits near {noise}: as stated {self.stated.residual_text}, the best "
            f"other reading ({best.mistake}) {best.residual_text}; {check}, and the units"
        )


def alternative_conventions(stated: PoseConvention) -> list[tuple[str, PoseConvention]]:
    """The common mistakes from a stated convention: (what it means in words, the convention)."""
    out = [
        (
            f"{_other(stated.direction)} (inverted)",
            replace(stated, direction=_other(stated.direction)),
        ),
        (
            f"lengths in {_swap(stated.length_unit, 'm', 'mm')}",
            replace(stated, length_unit=_swap(stated.length_unit, "m", "mm")),
        ),
    ]
    rotation = stated.rotation
    if rotation.startswith("quat"):
        other = _swap(rotation, "quat-wxyz", "quat-xyzw")
        out.append((f"quaternions {other.removeprefix('quat-')}", replace(stated, rotation=other)))
    elif rotation != "matrix":
        out.append(
            (
                f"angles in {_swap(stated.angle_unit, 'rad', 'deg')}",
                replace(stated, angle_unit=_swap(stated.angle_unit, "rad", "deg")),
            )
        )
        kinds = ["rotvec", *(f"euler-{s}" for s in EULER_SEQUENCES)]
        for kind in kinds:
            if kind != rotation:
                words = (
                    "a rotation vector" if kind == "rotvec" else f"Euler angles {kind.removeprefix('euler-')}"
                )
                out.append((words, replace(stated, rotation=kind)))
    return out


def check_pose_convention(
    problem: CalibrationProblem, values: np.ndarray, stated: PoseConvention
) -> ConventionReport:
    """Try the stated convention, every mistake and the pairing shifts on the problem's board
    observations (module doc). values: (N, k) the pose file's numbers of the dataset's frames, row i
    for frame i (problem frames name theirs)."""
    values = np.asarray(values, dtype=np.float64)
    noise = data_noise_px(problem)
    stated_trial = _trial(problem, values, "", stated)
    try:
        cannot = _degenerate_motion(poses_from_values(values, stated)[[f.frame for f in problem.frames]])
    except PoseFileError:
        cannot = None
    if cannot is not None:
        return ConventionReport(stated_trial, [], None, noise, cannot)
    others = [_trial(problem, values, m, c, stated) for m, c in alternative_conventions(stated)]
    for shift in SHIFTS:
        # Reading image i with row i + shift fits when the file paired it with its neighbour's pose.
        words = "each image paired with the " + ("previous" if shift > 0 else "next") + " image's pose"
        others.append(_trial(problem, values, words, stated, stated, shift))
    best = min(others, key=lambda t: t.residual_px)
    named = (
        best.residual_px < MISTAKE_RATIO * stated_trial.residual_px
        and best.residual_px <= NOISE_RATIO * noise
    )
    return ConventionReport(stated_trial, others, best if named else None, noise)


def _degenerate_motion(T_base_flange: np.ndarray) -> str | None:
    """Why the flange's motion (N, 4, 4) cannot tell pose readings apart, or None: no rotation
    between views, or rotations about one axis only."""
    R = T_base_flange[:, :3, :3]
    i, j = np.triu_indices(len(R), k=1)
    rotvecs = Rotation.from_matrix(np.swapaxes(R[i], 1, 2) @ R[j]).as_rotvec()
    angles = np.degrees(np.linalg.norm(rotvecs, axis=1))
    largest = float(angles.max()) if len(angles) else 0.0
    if largest < MIN_ROTATION_DEG:
        return (
            f"the flange barely rotates between views (at most {largest:.2g} deg), so every reading of "
            "the rotations fits alike; record views turned about two axes (hec plan proposes them)"
        )
    axes = rotvecs[angles >= MIN_ROTATION_DEG] / np.radians(angles[angles >= MIN_ROTATION_DEG])[:, None]
    spread = np.degrees(
        np.arcsin(min(1.0, float(np.linalg.svd(axes, compute_uv=False)[1]) / np.sqrt(len(axes))))
    )
    if spread < AXIS_SPREAD_DEG:
        return (
            "the flange rotates about one axis only between views, so the readings cannot be told apart "
            "(and no hand-eye method can find the mount along that axis); record views turned about two axes"
        )
    return None


def _trial(
    problem: CalibrationProblem,
    values: np.ndarray,
    mistake: str,
    convention: PoseConvention,
    stated: PoseConvention | None = None,
    shift: int = 0,
) -> ConventionTrial:
    changed = tuple(
        k for k, v in convention.to_dict().items() if stated is not None and stated.to_dict()[k] != v
    )
    try:
        T_base_flange = poses_from_values(values, convention)
        frames = [
            replace(f, T_base_flange=model_pose(problem.setup, T_base_flange[f.frame + shift]), joints=None)
            for f in problem.frames
            if 0 <= f.frame + shift < len(T_base_flange)
        ]
        result = opencv_calibrate(
            replace(problem, frames=frames, kinematics=None), MethodOptions(), "opencv-park"
        )
        residual = result.residual_rms_px
    except (CalibrationInputError, PoseFileError, ValueError, np.linalg.LinAlgError):
        residual = float("inf")
    residual = residual if np.isfinite(residual) else float("inf")
    return ConventionTrial(mistake, convention, residual, changed, shift)


def _other(direction: str) -> str:
    return _swap(direction, "base-to-flange", "flange-to-base")


def _swap(value: str, a: str, b: str) -> str:
    return b if value == a else a


@dataclass(frozen=True)
class PairReading:
    """One reading of imported pose pairs: the mistake in words ("" as stated), the options that
    select it, the RMS translation (metres) of the board pose over the pairs at Park's solution for
    it (inf when Park fails) and the lengths (metres) of that solution's mount and board translations."""

    mistake: str
    option: str
    residual_m: float
    mount_m: float = float("nan")
    board_m: float = float("nan")


@dataclass(frozen=True)
class PairCheck:
    """What check_pose_pair_directions found: its sentence, and whether the pairs fit as stated
    (fits), fit another reading better (a mistake, to refuse) or cannot tell (cannot_check)."""

    message: str
    mistake: bool = False
    cannot_check: bool = False


def check_pose_pair_directions(
    pairs: list[PosePair], robot_direction: str, tracking_direction: str
) -> PairCheck:
    """Which reading of pose pairs fits: as stated (pairs read in robot_direction and
    tracking_direction), the robot poses inverted, the camera-to-target poses inverted, or both; in
    words, with the residual before and after (the board pose's RMS translation over the pairs at
    Park's solution). Robot motion that cannot tell the readings apart (no rotation, one axis, the
    same pose throughout) is 'cannot check'.

    Inverting both fits exactly as well as not, with the roles swapped: the mount comes out as the
    board's pose in the base frame and the board's as the mount. So only readings that put the
    camera nearer the flange than the board is to the base are taken (a camera on a flange is not
    across the cell from it), unless none does."""
    cannot = _degenerate_motion(np.array([p.T_base_flange for p in pairs]))
    if cannot is not None:
        return PairCheck(f"cannot check the pose pairs' directions: {cannot}", cannot_check=True)
    other_robot, other_tracking = _other(robot_direction), _swap(tracking_direction, *TRACKING_DIRECTIONS)
    readings = [
        ("", "", False, False),
        (f"robot poses {other_robot} (inverted)", f"--pose-direction {other_robot}", True, False),
        (
            f"tracking poses {other_tracking} (inverted)",
            f"--tracking-direction {other_tracking}",
            False,
            True,
        ),
        (
            "both inverted",
            f"--pose-direction {other_robot} --tracking-direction {other_tracking}",
            True,
            True,
        ),
    ]
    trials = [_pair_reading(pairs, m, o, a, z) for m, o, a, z in readings]
    stated = trials[0]
    if not any(np.isfinite(t.residual_m) for t in trials):
        return PairCheck(
            "cannot check the pose pairs' directions: Park finds no solution in any reading (poses that "
            "repeat, or too few)",
            cannot_check=True,
        )
    best = min([t for t in trials if t.mount_m < t.board_m] or trials, key=lambda t: t.residual_m)
    if best is not stated and best.residual_m < MISTAKE_RATIO * stated.residual_m:
        after = f"{1e3 * best.residual_m:.3g} mm"
        change = (
            f"as stated Park finds no solution, read so the board pose's spread is {after}"
            if not np.isfinite(stated.residual_m)
            else f"the board pose's spread drops from {1e3 * stated.residual_m:.3g} mm to {after}"
        )
        return PairCheck(
            f"the pose pairs look like {best.mistake}: {change}; pass {best.option}", mistake=True
        )
    if best is not stated and not stated.mount_m < stated.board_m:
        return PairCheck(
            f"the pose pairs look like {best.mistake}: they fit as well either way (board pose spread "
            f"{1e3 * stated.residual_m:.3g} mm as stated, {1e3 * best.residual_m:.3g} mm read so), but as "
            f"stated the camera sits {stated.mount_m:.2f} m from the flange and the board "
            f"{stated.board_m:.2f} m from the base, read so {best.mount_m:.2f} m and {best.board_m:.2f} m; "
            f"pass {best.option}",
            mistake=True,
        )
    return PairCheck(
        f"the pose pairs fit the stated directions (the board pose's spread {1e3 * stated.residual_m:.3g} mm "
        "RMS); none of the common mistakes fits better"
    )


def _pair_reading(
    pairs: list[PosePair], mistake: str, option: str, invert_robot: bool, invert_tracking: bool
) -> PairReading:
    read = [
        PosePair(
            p.frame,
            invert(p.T_base_flange) if invert_robot else p.T_base_flange,
            invert(p.T_cam_board) if invert_tracking else p.T_cam_board,
        )
        for p in pairs
    ]
    try:
        X, B = opencv_pose_pairs(read, "opencv-park")
    except (CalibrationInputError, np.linalg.LinAlgError, ValueError):
        return PairReading(mistake, option, float("inf"))
    residual = PosePairModel(read, PAIR_NOISE_FREE).rms(X, B)[0]
    return PairReading(
        mistake, option, residual, float(np.linalg.norm(X[:3, 3])), float(np.linalg.norm(B[:3, 3]))
    )


def check_board_layout(problem: CalibrationProblem) -> str:
    """Whether the board file's marker layout fits the images, or fits them mirrored (the markers'
    centres reflected left to right or top to bottom about the board's origin, each marker's own
    points kept, as a board file written in a frame with x or y the other way would be); in words,
    with the RMS pixel residual of each frame's board pose (PnP) before and after. A board of
    one-point markers mirrored is the same points seen from behind, a rigid change the board pose
    absorbs: nothing to name. A residual far above the corners' declared noise that no mirroring
    removes is named as such (the camera model, not the layout)."""
    stated = board_residual_px(problem, np.ones(3))
    readings = [
        ("left to right (x)", np.array([-1.0, 1.0, 1.0])),
        ("top to bottom (y)", np.array([1.0, -1.0, 1.0])),
    ]
    words, residual = min(((w, board_residual_px(problem, m)) for w, m in readings), key=lambda t: t[1])
    if residual < MISTAKE_RATIO * stated:
        return (
            f"the board file's marker layout looks mirrored {words}: the residual of the board poses drops "
            f"from {stated:.3g} px to {residual:.3g} px with the markers' centres reflected; correct the "
            "board file's marker centres"
        )
    sigma = declared_corner_sigma_px(problem)
    if stated > NOISE_RATIO * sigma:
        return (
            f"the board poses leave {stated:.2g} px RMS, {stated / sigma:.0f} times the corners' noise "
            f"({sigma:.2g} px), and no better mirrored: the board file's layout is not the cause, but the "
            "intrinsics or lens model (or a board that is not flat) do not match the images; check the "
            "camera's calibration"
        )
    return f"the board file's layout fits the images ({stated:.2g} px RMS residual of the board poses)"

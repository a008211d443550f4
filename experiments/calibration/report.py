"""The text and JSON forms of a calibration result (format_calibration, calibration_to_dict), shared by
every command that reports (the comparison table of several methods is hec.calibration.comparison)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hec.calibration.loo import format_loo, loo_to_dict
from hec.estimator.common.files import check_output_file, write_atomic
from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.common.setups import (
    BOARD_POSE_NAMES,
    EYE_IN_HAND,
    EYE_TO_HAND,
    HAND_EYE_MEANINGS,
    HAND_EYE_NAMES,
)
from hec.estimator.geometry.lie import pose_minus, so3_log
from hec.estimator.geometry.transforms import pose_error, rpy_from_transform, xyz_quat_from_transform
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.pick_error import PickError, pick_error, true_pick_error_mm, working_distance
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import MARKER_SHIFTS, NUISANCE_GROUPS

TRANSFORM_MEANING = (
    "T_flange_cam: the camera optical frame (x right, y down, z forward) in the flange (tool0) frame; "
    "OpenCV's cam2gripper. Use: T_base_cam = T_base_flange @ T_flange_cam"
)
RPY_CONVENTION = "about the fixed flange axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll)"


COVARIANCE_CONVENTION = (
    "6x6 covariance of the perturbation (dt, dtheta) with R = R_est Exp(dtheta), t = t_est + dt: "
    "dt_x, dt_y, dt_z in metres along the flange axes, then dtheta_x, dtheta_y, dtheta_z in radians "
    "about the camera axes"
)
NO_UNCERTAINTY = "none (OpenCV gives no uncertainty)"


WORST_SHOWN = 3
PICK_KEY = "pick_error"


def pose_numbers(T: np.ndarray) -> dict:
    """A (4, 4) pose in the forms people use: translation_mm, quaternion_wxyz, rotation_vector_rad,
    rotation_angle_deg, rpy_deg (RPY_CONVENTION)."""
    t, q = xyz_quat_from_transform(T)
    rotvec = so3_log(T[:3, :3])
    return {
        "translation_mm": (1e3 * t).tolist(),
        "quaternion_wxyz": q.tolist(),
        "rotation_vector_rad": rotvec.tolist(),
        "rotation_angle_deg": float(np.degrees(np.linalg.norm(rotvec))),
        "rpy_deg": np.degrees(rpy_from_transform(T)).tolist(),
    }


def ground_truth_errors(cal: Calibration, T_true: np.ndarray) -> dict:
    """error_translation_mm, error_rotation_deg (geodesic) and, with a covariance, error_nees:
    the error normalised by the covariance (6 on average when the covariance is honest)."""
    dt, dr = pose_error(cal.T_flange_cam, T_true)
    out = {"error_translation_mm": 1e3 * dt, "error_rotation_deg": float(np.degrees(dr)), "error_nees": None}
    if cal.covariance is not None:
        delta = pose_minus(T_true, cal.T_flange_cam)
        out["error_nees"] = float(delta @ np.linalg.solve(cal.covariance, delta))
    return out


def add_pick_error(cal: Calibration, problem: CalibrationProblem) -> None:
    """cal.diagnostics[PICK_KEY]: the pick error (hec.estimator.solve.pick_error) of a result with a
    covariance and a board pose or landmarks; nothing otherwise."""
    if cal.covariance is None:
        return
    if cal.T_base_board is not None:
        centre_base = cal.T_base_board[:3, 3]
    elif cal.landmarks_base:
        centre_base = np.mean(np.concatenate(list(cal.landmarks_base.values())), axis=0)
    else:
        return
    distance = working_distance(problem, cal.T_flange_cam, centre_base)
    cal.diagnostics[PICK_KEY] = pick_error(cal.T_flange_cam, cal.covariance, distance)


def pick_dict(cal: Calibration, T_true: np.ndarray | None) -> dict | None:
    pick: PickError | None = cal.diagnostics.get(PICK_KEY)
    if pick is None:
        return None
    truth = None if T_true is None else true_pick_error_mm(cal.T_flange_cam, T_true, pick.distance_m)
    return pick.to_dict() | {"true_mm": truth}


def _format_pick(cal: Calibration, T_true: np.ndarray | None) -> list[str]:
    pick = pick_dict(cal, T_true)
    if pick is None:
        return []
    truth = "" if pick["true_mm"] is None else f"; against the truth {pick['true_mm']:.3f} mm"
    return [
        f"pick error at the working distance ({1e3 * pick['distance_m']:.0f} mm, a point on the optical "
        f"axis) in the base frame, from the uncertainty: {pick['rms_mm']:.3f} mm RMS, 95 % within "
        f"{pick['p95_mm']:.3f} mm{truth}"
    ]


def _worst_markers(cal: Calibration) -> list:
    return sorted((r for r in cal.residuals if r.used), key=lambda r: -r.rms_px)[:WORST_SHOWN]


def _worst_frames(cal: Calibration) -> list[tuple[int, float]]:
    return sorted(cal.frame_residuals().items(), key=lambda item: -item[1])[:WORST_SHOWN]


def rss(values: np.ndarray | None) -> float | None:
    return None if values is None else float(np.sqrt(np.sum(np.square(values))))


def format_matrix(T: np.ndarray) -> str:
    return "\n".join("  [" + "  ".join(f"{v:+.6f}" for v in row) + "]" for row in T)


def format_vector(values: Iterable[float], fmt: str) -> str:
    return " ".join(format(float(v), fmt) for v in values)


def _parent_axes(setup: str) -> str:
    """The frame the calibrated transform's translation (and its rpy) is along: flange or base."""
    return "base" if setup == EYE_TO_HAND else "flange"


def _format_pose(T: np.ndarray, setup: str = EYE_IN_HAND) -> list[str]:
    n = pose_numbers(T)
    meaning = TRANSFORM_MEANING if setup == EYE_IN_HAND else f"T_base_cam: {HAND_EYE_MEANINGS[setup]}"
    return [
        meaning,
        format_matrix(T),
        f"  translation [mm]: {format_vector(n['translation_mm'], '+.3f')}",
        f"  quaternion (w x y z): {format_vector(n['quaternion_wxyz'], '+.6f')}",
        f"  rotation vector [rad]: {format_vector(n['rotation_vector_rad'], '+.6f')}"
        f" (angle {n['rotation_angle_deg']:.4f} deg)",
        f"  roll-pitch-yaw [deg] ({RPY_CONVENTION.replace('flange', _parent_axes(setup))}): "
        f"{format_vector(n['rpy_deg'], '+.4f')}",
    ]


def _format_uncertainty(cal: Calibration) -> list[str]:
    if cal.covariance is None:
        lines = [f"uncertainty (1 sigma): {NO_UNCERTAINTY}"]
    else:
        lines = [
            f"uncertainty (1 sigma): translation [mm] along {_parent_axes(cal.setup)} x y z: "
            f"{format_vector(cal.sigma_translation_mm, '.4f')}; rotation [deg] about camera x y z: "
            f"{format_vector(cal.sigma_rotation_deg, '.5f')}"
        ]
    report = cal.diagnostics.get("observability")
    if report is not None and report.observable:
        lines.append(
            "Cramer-Rao bound (1 sigma, the best any method can do from these views): translation [mm] "
            f"{format_vector(report.crb_sigma_translation_mm, '.4f')}; rotation [deg] "
            f"{format_vector(report.crb_sigma_rotation_deg, '.5f')}"
        )
    elif report is not None:
        lines.append("Cramer-Rao bound: not finite, the mount is not observable from these views")
    if cal.depth_scale is not None:
        sigma = "" if cal.depth_scale_sigma is None else f" +- {cal.depth_scale_sigma:.6f}"
        lines.append(
            f"depth scale: {cal.depth_scale:.6f}{sigma} (measured depth = scale x true depth: divide "
            "measured depths by it)"
        )
    return lines


def _format_residuals(cal: Calibration) -> list[str]:
    if "pose_pair_rms" in cal.diagnostics:  # calibrated from pose pairs: no pixels
        t, r = cal.diagnostics["pose_pair_rms"]
        return [
            f"residuals of the board poses (at the reported flange poses): RMS {1e3 * t:.3f} mm, "
            f"{np.degrees(r):.4f} deg"
        ]
    depth = cal.residual_depth_rms_mm
    depth_text = "no depth" if depth is None else f"depth RMS {depth:.3f} mm"
    frames = ", ".join(f"{f} ({v:.3f} px)" for f, v in _worst_frames(cal)) or "-"
    markers = ", ".join(
        f"frame {r.frame} marker {r.marker_id} ({r.rms_px:.3f} px)" for r in _worst_markers(cal)
    )
    lines = [
        f"residuals (at the reported flange poses): RMS {cal.residual_rms_px:.3f} px, {depth_text}",
        f"  worst frames: {frames}",
        f"  worst markers: {markers or '-'}",
    ]
    rejected = [r for r in cal.residuals if not r.used]
    if rejected:
        shown = ", ".join(f"frame {r.frame} marker {r.marker_id} ({r.rms_px:.3f} px)" for r in rejected[:5])
        more = f" and {len(rejected) - 5} more" if len(rejected) > 5 else ""
        lines.append(f"  rejected by the outlier gate (residual at the estimate): {shown}{more}")
    return lines


def chi2_dof(cal: Calibration) -> float | None:
    """The measurements' chi-square per degree of freedom at the declared noise, if known."""
    noise = cal.diagnostics.get("noise")
    return None if noise is None else noise.chi2_dof


def _format_noise(cal: Calibration) -> list[str]:
    """The noise levels learned from the data beside the declared ones, and the goodness of fit."""
    noise = cal.diagnostics.get("noise")
    if "learned_pose_sigma" in cal.diagnostics:  # pose pairs: the warning gives the learned levels
        return []
    if noise is None:
        return ["noise: as declared (not learned from the data)"]
    learnt, declared = noise.learned, noise.declared
    ratios = noise.ratios
    fit = ", ".join(f"{name.replace('_', ' ')} {ratios[name]:.2f}" for name in ratios)

    def arm(robot: RobotPoseNoise) -> str:
        return f"{1e3 * robot.translation_sigma_m:.3f} mm / {np.degrees(robot.rotation_sigma_rad):.4f} deg"

    return [
        f"noise learned from the data: corners {learnt.pixel_scale:.2f}x the detector's sigma, depth "
        f"{learnt.depth_scale:.2f}x the depth model's, arm pose {arm(learnt.robot)} (declared "
        f"{arm(declared.robot)}); the estimate and its uncertainty use the learned levels "
        f"({1e3 * noise.time_s:.0f} ms)",
        f"goodness of fit: chi-square per degree of freedom at the declared noise {noise.chi2_dof:.2f} "
        f"(1 = the model fits; {fit})",
        *([] if noise.depth is None else [noise.depth.describe()]),
        *_format_prior_scale(noise),
    ]


def _format_prior_scale(noise: LearnedNoise) -> list[str]:
    """The self-calibration's groups and the widths of their priors learned from the corrections
    (hec.estimator.solve.prior_scale: x the declared prior's sigma, the same within a group)."""
    if noise.theta is None or noise.theta_prior_scale is None:
        return []
    group_of = {name: g for g in NUISANCE_GROUPS for name in NUISANCE_GROUPS[g]}
    scale = {
        group_of.get(name, MARKER_SHIFTS): float(s)
        for name, s in zip(noise.theta_names, noise.theta_prior_scale, strict=True)
    }
    widths = ", ".join(f"{group.replace('_', ' ')} {s:.2f}x" for group, s in scale.items())
    return [
        f"self-calibration: the priors' widths learned from the corrections (x the declared sigma): {widths}"
    ]


def _format_run(cal: Calibration) -> list[str]:
    d = cal.diagnostics
    start = f"; start: {d['initialisation']}" if d.get("initialisation") else ""
    return [
        f"observations: {cal.observations_used} used, {cal.observations_rejected} rejected",
        f"solver: {d.get('iterations', '?')} iterations, {1e3 * d.get('time_s', float('nan')):.1f} ms{start}",
    ]


def format_calibration(cal: Calibration, T_true: np.ndarray | None = None) -> str:
    """The full text report of one Calibration; with T_true (4, 4) its errors against it."""
    lines = [f"method: {cal.method}", *_format_pose(cal.T_flange_cam, cal.setup), *_format_uncertainty(cal)]
    lines += _format_pick(cal, T_true)
    lines += [*_format_residuals(cal), *_format_noise(cal), *format_loo(cal), *_format_run(cal)]
    lines += [f"warning: {w}" for w in cal.warnings] or ["warnings: none"]
    if T_true is not None:
        e = ground_truth_errors(cal, T_true)
        nees = (
            ""
            if e["error_nees"] is None
            else f"; normalised error (NEES, ~6 if honest) {e['error_nees']:.2f}"
        )
        lines.append(
            f"vs ground truth: translation error {e['error_translation_mm']:.3f} mm, "
            f"rotation error {e['error_rotation_deg']:.4f} deg (geodesic){nees}"
        )
    return "\n".join(lines)


def _floats(a: np.ndarray | None) -> list | None:
    return None if a is None else np.asarray(a, dtype=np.float64).tolist()


def calibration_to_dict(cal: Calibration, T_true: np.ndarray | None = None) -> dict:
    """The JSON form of one Calibration (SI inside the matrices, mm/deg where the key says so);
    with T_true (4, 4) the errors against it."""
    d = cal.diagnostics
    report = d.get("observability")
    data = {
        "method": cal.method,
        "transform": TRANSFORM_MEANING,
        "T_flange_cam": _floats(cal.T_flange_cam),
        **pose_numbers(cal.T_flange_cam),
        "rpy_convention": RPY_CONVENTION,
        "covariance": _floats(cal.covariance),
        "covariance_convention": COVARIANCE_CONVENTION,
        "sigma_translation_mm": _floats(cal.sigma_translation_mm),
        "sigma_rotation_deg": _floats(cal.sigma_rotation_deg),
        PICK_KEY: pick_dict(cal, T_true),
        "T_base_board": _floats(cal.T_base_board),
        "landmarks_base": None
        if cal.landmarks_base is None
        else {str(i): _floats(c) for i, c in cal.landmarks_base.items()},
        "depth_scale": cal.depth_scale,
        "depth_scale_sigma": cal.depth_scale_sigma,
        "residual_rms_px": cal.residual_rms_px,
        "residual_depth_rms_mm": cal.residual_depth_rms_mm,
        "frame_residuals": [{"frame": f, "rms_px": v} for f, v in cal.frame_residuals().items()],
        "marker_residuals": [asdict(r) for r in cal.residuals],
        "observations_used": cal.observations_used,
        "observations_rejected": cal.observations_rejected,
        "iterations": d.get("iterations"),
        "time_s": d.get("time_s"),
        "initialisation": d.get("initialisation"),
        "observability": None if report is None else report.to_dict(),
        "noise": None if d.get("noise") is None else d["noise"].to_dict(),
        "fit": None if d.get("fit") is None else d["fit"].to_dict(),
        **loo_to_dict(cal),
        "warnings": list(cal.warnings),
    }
    if T_true is not None:
        data |= ground_truth_errors(cal, T_true)
    if cal.setup == EYE_TO_HAND:  # the unknowns under their own names (setup_roles)
        data = {
            "setup": cal.setup,
            **{HAND_EYE_NAMES[cal.setup] if k == "T_flange_cam" else k: v for k, v in data.items()},
        }
        data["transform"] = f"{HAND_EYE_NAMES[cal.setup]}: {HAND_EYE_MEANINGS[cal.setup]}"
        data[BOARD_POSE_NAMES[cal.setup]] = data.pop("T_base_board")
        data["covariance_convention"] = COVARIANCE_CONVENTION.replace("the flange axes", "the base axes")
        data["rpy_convention"] = RPY_CONVENTION.replace("flange", "base")
    return data


def result_to_dict(result: Result, T_true: np.ndarray | None = None) -> dict:
    if isinstance(result, MethodFailure):
        return {"method": result.method, "error": result.error}
    return calibration_to_dict(result, T_true)


def _finite(value: object) -> object:
    """value with numpy scalars and arrays as Python ones, and every NaN or infinite float
    replaced by None (JSON has neither)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


@dataclass(frozen=True)
class MethodFailure:
    """A method that could not calibrate from these observations, and why."""

    method: str
    error: str


Result = Calibration | MethodFailure


def check_json_path(path: Path) -> None:
    """check_output_file for a JSON file: refused now rather than after the work."""
    check_output_file(path, "a JSON file name")


def write_json(path: Path, data: dict) -> Path:
    """Write data to path through a temporary sibling and a rename: never half-written.
    NaN and infinite numbers are written as null."""
    check_json_path(path)
    return write_atomic(path, json.dumps(_finite(data), indent=1, allow_nan=False) + "\n")

"""Does the model fit the data? The chi-square per degree of freedom of each measurement group at
the declared noise, and, where a group fits worse than its noise, the likely cause read from the
pattern of its residuals, in plain words.

Patterns looked for (each a warning with the figures that support it):
- the arm: the flange poses disagree with each other more than the declared robot noise;
- the image model: pixel residuals growing toward the image border (intrinsics or distortion);
- the board: the board looking larger or smaller than its definition in every view (print scale
  or board file);
- depth: depth residuals that grow with distance or are offset (a depth scale or offset bias),
  or that are simply larger than the depth noise model;
- self-calibration that could not separate the print scale from the depth scale (views at one
  distance);
- the prior: the user's prior and the data disagree (Mahalanobis distance);
- rejections: more than MAX_REJECTED_FRACTION of the observations left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from hec.estimator.solve.finding_check import SIGNIFICANT, check_findings
from hec.estimator.solve.measurement_model import predict_frame
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import (
    KINEMATIC_NUISANCE,
    MARKER_SHIFTS,
    NOTEWORTHY_MARKER_SHIFT_M,
    PRIOR_SIGMA,
    SCALE_CORRELATION,
    adjusted_problem,
    print_depth_scale_correlation,
)
from hec.estimator.solve.setup_roles import flange_minus

# A group fits badly when its chi-square per degree of freedom at the declared noise exceeds this
# (its learned sigma is then more than 1.5x the declared one).
BAD_FIT = 2.25
MAX_REJECTED_FRACTION = 0.10
PRIOR_CONFLICT_PROBABILITY = 1e-3
# A residual pattern is reported when it explains at least this share of the residual's variance.
PATTERN_SHARE = 0.3
# ... and the depth scale is "left to the priors" when its sigma exceeds this fraction of its
# prior's: 0.7 on an orbit of the default angles, 0.03-0.1 on the default two-distance views.
SCALE_UNRESOLVED = 0.25
# The arm's corrected kinematics are reported when they move the flange poses by this much (RMS).
NOTEWORTHY_FLANGE_MOVE_M = 0.0002
NOTEWORTHY_FLANGE_TURN_RAD = float(np.radians(0.01))
# Between the self-calibration warning's cause and its findings (each a cause and a fix, "; " apart).
# The groups _scale_ambiguity speaks of (the self-calibration's "cannot tell apart" does not repeat it).
SCALE_PAIR = ("board_scale", "depth_bias")
SELF_CALIBRATED = " (self-calibration; the mount's covariance includes their uncertainty): "


@dataclass
class FitCheck:
    """chi2_dof: per group at the declared noise (1 when the model fits), 'all measurements' for
    pixels and depth together. patterns: named figures (radial growth, board scale, depth trend;
    advice_<group> 1 for each self-calibration group given as advice, finding_holds_<group> for each
    significant one).
    warnings: plain words, the likely cause first."""

    chi2_dof: dict[str, float]
    patterns: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"chi2_per_dof_declared": self.chi2_dof, "patterns": self.patterns, "warnings": self.warnings}


def check_fit(problem: CalibrationProblem, learned: LearnedNoise, rejected: int) -> FitCheck:
    """The fit of the learning pass's optimum (learned.state) to the problem. rejected: observations
    the method left out."""
    prior_distance = learned.prior_distance
    check = FitCheck(dict(learned.ratios, **{"all measurements": learned.chi2_dof}))
    declared, learnt = learned.declared.robot, learned.learned.robot
    ratio = check.chi2_dof
    # The groups' fit with the self-calibrated camera, board and depth, when they were: a wrong
    # print scale also strains the flange poses and the depths under the declared model.
    after = learned.ratios_after or ratio
    if max(after.get("robot_translation", 0), after.get("robot_rotation", 0)) > BAD_FIT:
        check.warnings.append(
            f"the arm is less exact than declared: its pose noise, learned from the data, is "
            f"{1e3 * learnt.translation_sigma_m:.2f} mm / {np.degrees(learnt.rotation_sigma_rad):.3f} deg, "
            f"the dataset declares {1e3 * declared.translation_sigma_m:.2f} mm / "
            f"{np.degrees(declared.rotation_sigma_rad):.3f} deg ({_arm_accuracy(problem.arm_name)}): the "
            "learned level is used"
        )
    depth = learned.depth
    if depth is not None and not depth.used and not depth.agrees:
        check.patterns["depth_check_p"] = depth.p_value
        check.warnings.append(
            f"the depths disagree with the pixels: with them the mount moves {depth.shift_mm:.2f} mm / "
            f"{depth.shift_deg:.3f} deg (p = {depth.p_value:.2g}), and the corners and flange poses fit "
            f"{depth.misfit_depth:.2f}x their noise with them, {depth.misfit_pixels:.2f}x without; likely a "
            "depth-to-colour misregistration, correlated depth errors or flying pixels the model does not "
            "describe: calibrated from the pixels alone"
        )
    if learned.theta is None:
        if ratio.get("pixels", 0) > BAD_FIT:
            check.warnings += _pixel_patterns(problem, learned, check.patterns)
        if ratio.get("depth", 0) > BAD_FIT:
            check.warnings += _depth_pattern(problem, learned, check.patterns)
    else:
        check.warnings += _self_calibration(problem, learned, check.patterns)
        check.warnings += _scale_ambiguity(learned, check.patterns)
        check.warnings += _noise_left(after)
    if prior_distance is not None:
        check.patterns["prior_mahalanobis"] = float(np.sqrt(prior_distance))
        if chi2.sf(prior_distance, 6) < PRIOR_CONFLICT_PROBABILITY:
            check.warnings.append(
                f"the prior disagrees with the data: {np.sqrt(prior_distance):.1f} sigma apart "
                "(Mahalanobis, prior and data covariances together); check the prior file (a wrong "
                "axis or a 90-degree turn?) or widen its covariance"
            )
    total = problem.observation_count
    if total and rejected > MAX_REJECTED_FRACTION * total:
        cause = check.warnings[0] if check.warnings else "the model does not fit these observations"
        check.warnings.insert(
            0,
            f"{rejected} of {total} observations ({rejected / total:.0%}) were left out as outliers; "
            f"likely cause: {cause}",
        )
    return check


def _pixel_residuals(problem: CalibrationProblem, learned: LearnedNoise) -> tuple[np.ndarray, ...]:
    """Per used corner: measured minus predicted pixel (N, 2), the prediction (N, 2) and the
    predicted board centre in that frame (N, 2), at the learning pass's optimum."""
    residual, predicted, centre = [], [], []
    state = learned.state  # without self-calibration: the optimum under the declared camera and board
    for frame in problem.frames:
        keep = [(frame.frame, m.marker_id) not in learned.outliers for m in frame.markers]
        pred = predict_frame(problem, state, frame, jacobians=False)
        measured = np.concatenate([m.corners_px for m in frame.markers])
        mask = np.repeat(keep, problem.points_per_marker)
        residual.append((measured - pred.pixels)[mask])
        predicted.append(pred.pixels[mask])
        centre.append(np.broadcast_to(pred.pixels.mean(axis=0), (int(mask.sum()), 2)))
    return np.concatenate(residual), np.concatenate(predicted), np.concatenate(centre)


def _share(residual: np.ndarray, fitted: np.ndarray) -> float:
    """The share of the residual's sum of squares a fitted pattern explains."""
    total = float(np.sum(residual**2))
    return 0.0 if total == 0 else 1.0 - float(np.sum((residual - fitted) ** 2)) / total


def _pixel_patterns(problem: CalibrationProblem, learned: LearnedNoise, patterns: dict) -> list[str]:
    r, uv, centre = _pixel_residuals(problem, learned)
    k = problem.intrinsics
    words = [
        f"the corners fit {np.sqrt(learned.ratios['pixels']):.1f}x worse than their noise "
        f"(RMS residual {np.sqrt(np.mean(np.sum(r**2, axis=1))):.2f} px)"
    ]
    # Radial: the residual along the radius from the principal point, growing as r^3 (k1-like).
    xy = (uv - [k.cx, k.cy]) / [k.fx, k.fy]
    radius2 = np.sum(xy**2, axis=1, keepdims=True)
    basis = xy * radius2 * [k.fx, k.fy]
    coef = float(np.sum(basis * r) / max(np.sum(basis * basis), 1e-300))
    radial_share = _share(r, coef * basis)
    patterns["radial_share"] = radial_share
    # Board scale: the residual along the vector from the board's centre in the image.
    spread = uv - centre
    scale = float(np.sum(spread * r) / max(np.sum(spread * spread), 1e-300))
    scale_share = _share(r, scale * spread)
    patterns["board_scale_fraction"] = scale
    patterns["board_scale_share"] = scale_share
    causes = []
    if radial_share >= PATTERN_SHARE:
        causes.append(
            f"they grow toward the image border ({radial_share:.0%} of the residual is radial): the "
            f"intrinsics or the lens distortion are off (the dataset's distortion is {list(k.dist)}): "
            "calibrate the camera's intrinsics"
        )
    if scale_share >= PATTERN_SHARE:
        causes.append(
            f"the board looks {100 * scale:+.2f} % larger than its definition in every view "
            f"({scale_share:.0%} of the residual): check the print scale (the 100 mm bar) or the board file"
        )
    if not causes:
        causes.append("no pattern stands out: detection noise above the detector's estimate, or blur")
    return [words[0] + "; " + "; ".join(causes) + "; the learned pixel noise is used"]


def _depth_pattern(problem: CalibrationProblem, learned: LearnedNoise, patterns: dict) -> list[str]:
    measured, predicted = [], []
    for frame in problem.frames:
        pred = predict_frame(problem, learned.state, frame, jacobians=False)
        for k, m in enumerate(frame.markers):
            if m.depth_m is not None and (frame.frame, m.marker_id) not in learned.outliers:
                measured.append(m.depth_m)
                C = problem.points_per_marker
                predicted.append(pred.depth_m[C * k : C * k + C] / (learned.state.depth_scale or 1.0))
    z, z_pred = np.concatenate(measured), np.concatenate(predicted)
    A = np.column_stack([z_pred, np.ones_like(z_pred)])
    (slope, offset), *_ = np.linalg.lstsq(A, z - z_pred, rcond=None)
    trend_share = _share(z - z_pred, A @ [slope, offset])
    patterns.update(
        {"depth_scale_error": float(slope), "depth_offset_m": float(offset), "depth_trend_share": trend_share}
    )
    level = np.sqrt(learned.ratios["depth"])
    if trend_share >= PATTERN_SHARE:
        cause = (
            f"measured = true x {1 + slope:.4f} {1e3 * offset:+.2f} mm explains {trend_share:.0%} of its "
            "residual: either the depth is biased (run the camera's on-chip calibration or Tare) or the "
            "board is printed at another scale than its definition (check the 100 mm bar: from views at one "
            "distance the two look alike)"
        )
    else:
        cause = "no trend with distance: depth noisier than its model (spatially correlated, flying pixels?)"
    return [
        f"depth and pixels disagree: the depth fits {level:.1f}x worse than its noise; {cause}; the "
        "depth is kept with its learned (larger) noise, so pixels dominate"
    ]


def _noise_left(after: dict[str, float]) -> list[str]:
    """What still fits worse than its noise once the camera, board and depth are self-calibrated:
    noise above its model, which the learned levels carry."""
    words = []
    if after.get("pixels", 0) > BAD_FIT:
        words.append(
            f"even with the camera and board calibrated, the corners fit {np.sqrt(after['pixels']):.1f}x "
            "worse than their noise: detection noise above the detector's estimate, or blur; the "
            "learned pixel noise is used"
        )
    if after.get("depth", 0) > BAD_FIT:
        words.append(
            f"even with its scale and offset calibrated, the depth fits {np.sqrt(after['depth']):.1f}x "
            "worse than its noise: depth noisier than its model (spatially correlated, flying "
            "pixels?); the learned depth noise is used"
        )
    return words


def _self_calibration(problem: CalibrationProblem, learned: LearnedNoise, patterns: dict) -> list[str]:
    """What the self-calibration found: each group whose finding holds (significant, stable under
    the model's alternatives, weakly correlated: hec.estimator.solve.finding_check) with its likely
    cause and remedy (the arm's: the flange poses its corrected kinematics move, when that is
    NOTEWORTHY), then a "cannot tell apart" sentence for each significant one that does not hold.
    Records advice_<group> in patterns for each group given as advice."""
    t = dict(zip(learned.theta_names, learned.theta, strict=True))
    sigma = dict(zip(learned.theta_names, learned.theta_sigma, strict=True))
    patterns.update({f"self_calibration_{name}": float(v) for name, v in t.items()})
    checks = check_findings(problem, learned)
    patterns.update(
        {f"finding_holds_{group}": float(c.holds) for group, c in checks.items() if c.significant}
    )

    def found(group: str) -> bool:
        """Whether the group's finding is given as advice (hec.estimator.solve.finding_check)."""
        return group in checks and checks[group].holds

    findings = []
    if found("board_scale"):
        findings.append(
            f"the board is printed {100 * np.expm1(t['board_scale_x']):+.2f} % (x) and "
            f"{100 * np.expm1(t['board_scale_y']):+.2f} % (y) off its definition (+-"
            f"{100 * sigma['board_scale_x']:.2f} %): measure the print (its 100 mm bar) and correct the "
            "board file"
        )
    if found("board_bend"):
        findings.append(
            f"the board is bent out of its plane: its centre stands {1e3 * t['board_bend_x_m']:+.2f} mm "
            f"(along x) and {1e3 * t['board_bend_y_m']:+.2f} mm (along y) off its edges (+-"
            f"{1e3 * sigma['board_bend_x_m']:.2f} mm): mount it flat (glass or aluminium)"
        )
    if found("depth_bias"):
        gain = np.exp(t["depth_scale"])
        findings.append(
            f"the depth reads true x {gain:.4f} {1e3 * gain * t['depth_offset_m']:+.2f} mm (+-"
            f"{100 * sigma['depth_scale']:.2f} %, +-{1e3 * sigma['depth_offset_m']:.2f} mm): run the "
            "camera's on-chip calibration or Tare"
        )
    if found("depth_tilt"):
        findings.append(
            f"the depth tilts across the image by {1e3 * t['depth_tilt_x']:+.2f} mm (along x) and "
            f"{1e3 * t['depth_tilt_y']:+.2f} mm (along y) per metre (+-{1e3 * sigma['depth_tilt_x']:.2f}), "
            "as a depth-to-colour registration turned by "
            f"{np.degrees(np.hypot(t['depth_tilt_x'], t['depth_tilt_y'])):.3f} deg would: recalibrate "
            "the camera's depth-to-colour extrinsics"
        )
    if found("intrinsics"):
        findings.append(
            f"the intrinsics are off by fx {t['fx_px']:+.2f}, fy {t['fy_px']:+.2f}, cx {t['cx_px']:+.2f}, "
            f"cy {t['cy_px']:+.2f} px: calibrate the camera's intrinsics"
        )
    if found("distortion"):
        findings.append(
            f"the lens distortion differs from the dataset's by k1 {t['k1']:+.4f}, k2 {t['k2']:+.4f}: "
            "calibrate the camera's intrinsics with distortion"
        )
    advised = [
        g
        for g in ("board_scale", "board_bend", "depth_bias", "depth_tilt", "intrinsics", "distortion")
        if found(g)
    ]
    if KINEMATIC_NUISANCE[0] in t and found("kinematics"):
        arm = _kinematic_finding(problem, learned, patterns)
        findings += arm
        advised += ["kinematics"] if arm else []
    if found(MARKER_SHIFTS):
        markers = _marker_shift_finding(problem, t, sigma)
        findings += markers
        advised += [MARKER_SHIFTS] if markers else []
    patterns.update({f"advice_{group}": 1.0 for group in advised})
    undecided, pairs = [], {frozenset(SCALE_PAIR)} if _scale_ambiguity(learned, {}) else set()
    for check in checks.values():
        if check.significant and not check.holds and frozenset({check.group, check.partner}) not in pairs:
            pairs.add(frozenset({check.group, check.partner}))
            undecided.append(check.cannot_tell())
    if not findings:
        return undecided
    misfit = ", ".join(
        f"{word} {np.sqrt(learned.ratios[name]):.1f}x"
        for name, word in (("pixels", "corners"), ("depth", "depths"))
        if name in learned.ratios
    )
    return [
        f"the declared model did not fit (the {misfit} their noise), so the camera, board, depth and "
        "arm were calibrated with the mount where the data showed them off"
        + SELF_CALIBRATED
        + "; ".join(findings)
    ] + undecided


def _marker_shift_finding(problem: CalibrationProblem, t: dict, sigma: dict) -> list[str]:
    """The marker the self-calibration moved farthest off its definition, when that is more than
    SIGNIFICANT sigmas and NOTEWORTHY_MARKER_SHIFT_M."""
    shifts = {
        i: (
            np.hypot(t[f"marker{i}_x_m"], t[f"marker{i}_y_m"]),
            max(sigma[f"marker{i}_x_m"], sigma[f"marker{i}_y_m"]),
        )
        for i in problem.marker_ids
        if f"marker{i}_x_m" in t
    }
    found = {i: s for i, (s, sd) in shifts.items() if s > max(SIGNIFICANT * sd, NOTEWORTHY_MARKER_SHIFT_M)}
    if not found:
        return []
    worst = max(found, key=found.get)
    return [
        f"{len(found)} marker(s) sit off their place in the board file, marker {worst} most "
        f"({1e3 * found[worst]:.2f} mm, +-{1e3 * shifts[worst][1]:.2f} mm): measure the print, or print "
        "the board again at a print shop"
    ]


def _kinematic_finding(problem: CalibrationProblem, learned: LearnedNoise, patterns: dict) -> list[str]:
    """The flange poses the self-calibrated kinematics move (RMS and largest over the views), when
    the RMS is NOTEWORTHY."""
    adjusted = adjusted_problem(problem, learned.theta, learned.theta_names)
    moves = np.array(
        [
            flange_minus(problem.setup, a.T_base_flange, f.T_base_flange)
            for a, f in zip(adjusted.frames, problem.frames, strict=True)
        ]
    )
    translation_m, rotation_rad = np.linalg.norm(moves[:, :3], axis=1), np.linalg.norm(moves[:, 3:], axis=1)
    rms_m, rms_rad = float(np.sqrt(np.mean(translation_m**2))), float(np.sqrt(np.mean(rotation_rad**2)))
    patterns.update({"kinematic_correction_rms_m": rms_m, "kinematic_correction_rms_rad": rms_rad})
    if rms_m < NOTEWORTHY_FLANGE_MOVE_M and rms_rad < NOTEWORTHY_FLANGE_TURN_RAD:
        return []
    return [
        f"the arm's kinematics differ from the nominal {problem.kinematics.name} model: corrected, they move "
        f"the reported flange poses by {1e3 * rms_m:.2f} mm / {np.degrees(rms_rad):.3f} deg RMS (up to "
        f"{1e3 * translation_m.max():.2f} mm / {np.degrees(rotation_rad.max()):.3f} deg) over these views: "
        f"use the arm's own calibrated kinematics ({_calibrated_model(problem.arm_name)}) where the poses "
        "come from"
    ]


def _is_ur(arm_name: str | None) -> bool:
    return arm_name is not None and arm_name.lower().startswith("ur")


def _arm_accuracy(arm_name: str | None) -> str:
    """What an arm like the declared one achieves, in words (the arm-noise warning)."""
    if _is_ur(arm_name):
        return (
            f"the dataset declares a {arm_name.upper()}: a UR's absolute accuracy with nominal kinematics "
            "is millimetres, its repeatability 0.03-0.1 mm"
        )
    arm = "no arm" if arm_name is None else f"the arm {arm_name!r}"
    return (
        f"the dataset declares {arm}; an arm's absolute accuracy with its nominal kinematics is often "
        "millimetres, well above its repeatability"
    )


def _calibrated_model(arm_name: str | None) -> str:
    """Where the declared arm keeps its calibrated kinematics, in words."""
    return "a UR's calibration.conf" if _is_ur(arm_name) else "its controller's calibrated model"


def _scale_ambiguity(learned: LearnedNoise, patterns: dict) -> list[str]:
    """A warning when the views could not tell the board's print scale from the depth's scale:
    their estimates correlated beyond SCALE_CORRELATION and the depth scale's sigma more than
    SCALE_UNRESOLVED of its prior's (the split between the two then rests on their priors, and
    the mount's covariance carries it)."""
    correlation = print_depth_scale_correlation(learned.theta_names, learned.theta_covariance)
    if correlation is None:
        return []
    C, names = learned.theta_covariance, list(learned.theta_names)
    depth = np.zeros(len(names))
    depth[names.index("depth_scale")] = 1.0
    patterns["print_depth_scale_correlation"] = correlation
    resolved = np.sqrt(depth @ C @ depth) / PRIOR_SIGMA["depth_scale"]
    patterns["depth_scale_sigma_over_prior"] = float(resolved)
    if abs(correlation) < SCALE_CORRELATION or resolved < SCALE_UNRESOLVED:
        return []
    return [
        f"these views cannot tell the board's print scale from the depth's scale (their estimates "
        f"are {abs(correlation):.0%} correlated): both were estimated with wide priors, and the "
        "covariance of the mount includes what they leave open; add views nearer to and farther from "
        "the board (the default trajectory alternates 0.9 and 1.25 times its distance)"
    ]

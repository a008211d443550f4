"""Does a self-calibration finding hold? Advice only where it does.

A group of corrections the self-calibration kept (hec.estimator.solve.self_calibration.NUISANCE_GROUPS)
is given as advice (a cause and its fix) only when

- it is significant: a correction more than SIGNIFICANT sigmas from the declared model and
  NOTEWORTHY with one sigma taken off (from 6 views a lens term 0.0112 +- 0.0024 off, just beyond
  the 0.01 worth reporting, was advice on an exact lens);
- it is stable under the model's alternatives: without the depth scale and offset, and without the
  lens term (each dropped to first order: the group's estimate conditioned on the other at its
  declared value, from their joint covariance), it stays significant with the same sign; an
  alternative the data reject (its corrections differ from zero at GROUP_SIGNIFICANCE) is none;
- its estimate is weakly correlated with every other group that is a finding too, one the data
  need with a significant correction (the combination of its parameters the finding stands out
  along, C_GG^-1 theta_G, correlated with no parameter of theirs beyond CORRELATION_LIMIT; per
  parameter, one of the arm's 24 kinematic corrections that the views cannot pin down would speak
  for the whole finding): two such groups trading one for the other cannot both be advice. A group
  beside a well-determined one that the data do not need (intrinsics at zero beside a print scale
  18 sigma off), or need with corrections all insignificant or immaterial (intrinsics pinned to
  0.05 px beside a depth scale 35 sigma off, 94 % correlated), leaves the latter's marginal sigma
  to say how well it is known.

Otherwise the views cannot tell it apart from the group it trades with, and the report says so,
with what would separate them, instead of a fix. On a real set of 6 commanded views the board
print was "-1.18 % +- 0.11 %" and flipped to +1.1 % under --depth-scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import (
    GROUP_SIGNIFICANCE,
    NOTEWORTHY,
    NOTEWORTHY_MARKER_SHIFT_M,
    group_members,
)

# A correction is significant beyond this many sigmas from the declared model.
SIGNIFICANT = 3.0
# Two groups whose parameters' estimates correlate beyond this are not told apart.
CORRELATION_LIMIT = 0.9
# The model's alternatives a finding must survive: without the depth scale, without the lens term.
ALTERNATIVES = ("depth_bias", "distortion")
# What separates two groups, by the pair (any order); the default covers the rest.
SEPARATES = {
    frozenset({"board_scale", "depth_bias"}): "views nearer to and farther from the board",
    frozenset({"board_bend", "depth_bias"}): "views nearer to and farther from the board",
    frozenset(
        {"depth_tilt", "distortion"}
    ): "views with the board tilted the other way and in the image corners",
    frozenset({"depth_tilt", "intrinsics"}): "views with the board tilted the other way",
    frozenset({"distortion", "intrinsics"}): "views with the board in the image corners",
    frozenset({"board_scale", "intrinsics"}): "views nearer to and farther from the board",
}
DEFAULT_SEPARATION = "views at another distance and another tilt"
# The groups in words.
WORDS = {
    "intrinsics": "the intrinsics",
    "distortion": "the lens distortion",
    "board_scale": "the board's print scale",
    "depth_bias": "the depth's scale and offset",
    "board_bend": "the board's bend",
    "depth_tilt": "the depth's tilt",
    "kinematics": "the arm's kinematics",
    "marker_shifts": "the markers' places",
}


@dataclass(frozen=True)
class FindingCheck:
    """group: a kept self-calibration group; significant; correlation: the largest of its finding's
    (module doc) with another needed group's parameters, correlated_with: that group; undone_by:
    the alternative (ALTERNATIVES) without which it does not stay significant with its sign, None
    when it is stable."""

    group: str
    significant: bool
    correlation: float
    correlated_with: str | None
    undone_by: str | None

    @property
    def stable(self) -> bool:
        return self.undone_by is None

    @property
    def holds(self) -> bool:
        return self.significant and self.stable and self.correlation < CORRELATION_LIMIT

    @property
    def partner(self) -> str | None:
        """The group it cannot be told apart from (None when it holds)."""
        if self.holds:
            return None
        return self.correlated_with if self.correlation >= CORRELATION_LIMIT else self.undone_by

    def cannot_tell(self) -> str:
        """The sentence that replaces the advice when the finding does not hold (significant ones)."""
        correlated = self.correlation >= CORRELATION_LIMIT
        partner = self.partner
        other = WORDS.get(partner, "the rest of the model")
        why = (
            f"their estimates are {self.correlation:.0%} correlated"
            if correlated
            else f"without {other} the correction does not stay significant with its sign"
        )
        separate = SEPARATES.get(frozenset({self.group, partner}), DEFAULT_SEPARATION)
        return (
            f"these views cannot tell {WORDS[self.group]} apart from {other} ({why}): both are "
            f"estimated and the mount's covariance includes them, but neither is given as a fix; {separate} "
            "would separate them"
        )


def _noteworthy(names: list[str]) -> np.ndarray:
    return np.array(
        [NOTEWORTHY.get(n, NOTEWORTHY_MARKER_SHIFT_M if n.startswith("marker") else 0.0) for n in names]
    )


def _significant(theta: np.ndarray, sigma: np.ndarray, names: list[str]) -> np.ndarray:
    """Which corrections (n,) are more than SIGNIFICANT sigmas from the declared model and NOTEWORTHY
    with one sigma taken off (a size the data only just reach is no fix to make)."""
    return np.abs(theta) > np.maximum(SIGNIFICANT * sigma, _noteworthy(names) + sigma)


def _needed(theta: np.ndarray, covariance: np.ndarray) -> bool:
    """Whether the data reject a group's corrections (k,) being zero: their chi-square with their
    covariance (k, k) beyond the self-calibration's GROUP_SIGNIFICANCE."""
    return bool(chi2.sf(float(theta @ np.linalg.solve(covariance, theta)), len(theta)) < GROUP_SIGNIFICANCE)


def check_findings(problem: CalibrationProblem, learned: LearnedNoise) -> dict[str, FindingCheck]:
    """FindingCheck of every group the self-calibration kept (module doc), by group."""
    names = list(learned.theta_names)
    theta, C = learned.theta, learned.theta_covariance
    sigma = np.sqrt(np.diag(C))
    index = {
        g: [names.index(n) for n in group_members(problem, g) if n in names] for g in learned.groups_kept
    }
    index = {g: rows for g, rows in index.items() if rows}
    needed = {g for g, rows in index.items() if _needed(theta[rows], C[np.ix_(rows, rows)])}
    found_in = {
        g: _significant(theta[rows], sigma[rows], [names[i] for i in rows]) for g, rows in index.items()
    }
    # A finding trades only with a group that is a finding too: a group the data need whose
    # corrections are all insignificant or immaterial is pinned beside it (its marginal sigma says so).
    rivals = {g for g in needed if found_in[g].any()}
    checks = {}
    for group, rows in index.items():
        own = [names[i] for i in rows]
        found = found_in[group]
        others = [i for g, r in index.items() if g != group and g in rivals for i in r]
        rho, partner = 0.0, None
        if others and found.any():
            # The finding as a whole: the combination of the group's parameters its estimate stands out
            # along (a = C_GG^-1 theta_G), against each parameter of the rival groups.
            direction = np.linalg.solve(C[np.ix_(rows, rows)], theta[rows])
            spread = np.sqrt(direction @ C[np.ix_(rows, rows)] @ direction)
            along = np.abs(direction @ C[np.ix_(rows, others)]) / (spread * sigma[others])
            rho = float(along.max())
            partner = next(g for g, r in index.items() if others[int(np.argmax(along))] in r)
        undone_by = None
        for alternative in ALTERNATIVES:
            dropped = index.get(alternative, [])
            if alternative == group or alternative in needed or not dropped or not found.any():
                continue
            gain = C[np.ix_(rows, dropped)] @ np.linalg.inv(C[np.ix_(dropped, dropped)])
            theta_without = theta[rows] - gain @ theta[dropped]
            sigma_without = np.sqrt(
                np.maximum(np.diag(C[np.ix_(rows, rows)] - gain @ C[np.ix_(dropped, rows)]), 0.0)
            )
            kept = _significant(theta_without, sigma_without, own) & (
                np.sign(theta_without) == np.sign(theta[rows])
            )
            if not kept[found].any():
                undone_by = alternative
        checks[group] = FindingCheck(group, bool(found.any()), rho, partner, undone_by)
    return checks

"""The running estimate of a session as a picture: how T_flange_cam and its 1-sigma settle as
frames come in (written as DIR/session_estimate.png by `hec record` and `hec run`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hec.estimator.common.files import write_atomic
from hec.estimator.solve.calibration import Calibration
from hec.support.plotting import plain_log_axis

PLOT_FILE = "session_estimate.png"
_AXES = "xyz"


def plot_convergence(history: list[tuple[int, Calibration]], path: Path) -> Path:
    """history: (frames used, the estimate from them), in order. Top: each translation axis
    minus the final estimate, mm, with its 1-sigma band; then the translation and rotation
    1-sigma per axis (log). Returns path."""
    from io import BytesIO

    from matplotlib.figure import Figure

    with_sigma = [(k, c) for k, c in history if c.covariance is not None]
    frames = np.array([k for k, _ in with_sigma])
    t_mm = np.array([1e3 * c.T_flange_cam[:3, 3] for _, c in with_sigma])
    sigma_t = np.array([c.sigma_translation_mm for _, c in with_sigma])
    sigma_r = np.array([c.sigma_rotation_deg for _, c in with_sigma])
    fig = Figure(figsize=(7.5, 7.5), layout="constrained")
    top, middle, bottom = fig.subplots(3, 1, sharex=True)
    final = t_mm[-1]
    for i, axis in enumerate(_AXES):
        deviation = t_mm[:, i] - final[i]
        line = top.plot(frames, deviation, marker="o", ms=3, label=f"{axis} (final {final[i]:+.2f} mm)")[0]
        top.fill_between(
            frames, deviation - sigma_t[:, i], deviation + sigma_t[:, i], color=line.get_color(), alpha=0.15
        )
        middle.plot(frames, sigma_t[:, i], marker="o", ms=3, label=f"along flange {axis}")
        bottom.plot(frames, sigma_r[:, i], marker="o", ms=3, label=f"about camera {axis}")
    top.axhline(0.0, color="grey", lw=0.8)
    top.set_ylabel("translation - final [mm]\n(band: 1 sigma)")
    middle.set_ylabel("translation 1 sigma [mm]")
    bottom.set_ylabel("rotation 1 sigma [deg]")
    for ax in (middle, bottom):
        plain_log_axis(ax)
    for ax in (top, middle, bottom):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    bottom.set_xlabel("frames recorded")
    fig.suptitle(f"{with_sigma[-1][1].method}: the running estimate of T_flange_cam")
    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    return write_atomic(path, buffer.getvalue())

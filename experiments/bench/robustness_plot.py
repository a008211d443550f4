"""The robustness benchmark's picture (hec.bench.robustness --plot): per case the median
errors of every method with the best OpenCV method, the target and the bound, and the default
method's mean NEES against its band."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hec.estimator.solve.baselines import OPENCV_METHODS
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS


def plot(
    summaries: dict,
    path: str,
    best_opencv: Callable[[dict, str], str | None],
    target_ratio: float,
    nees_range: tuple[float, float],
) -> None:
    """Median translation and rotation error per case (hec's methods, the best OpenCV method and
    the bound) and the default method's mean NEES per case against the acceptance range.
    best_opencv(methods, key): the best OpenCV method of a case by that median."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(summaries)
    x = np.arange(len(keys))
    fig, axes = plt.subplots(3, 1, figsize=(max(9.0, 0.75 * len(keys) + 3), 11), sharex=True)
    hec = [m for m in METHODS if m not in OPENCV_METHODS]
    for ax, key, crb, unit in (
        (axes[0], "median_mm", "crb_error_median_mm", "mm"),
        (axes[1], "median_deg", "crb_error_median_deg", "deg"),
    ):
        for k, method in enumerate(hec):
            values = [summaries[c]["methods"][method].get(key, np.nan) for c in keys]
            ax.plot(x + 0.06 * (k - 2), values, "o", label=method, ms=6 if method == DEFAULT_METHOD else 4)
        best = [best_opencv(summaries[c]["methods"], key) for c in keys]
        values = [
            np.nan if b is None else summaries[c]["methods"][b][key] for c, b in zip(keys, best, strict=True)
        ]
        ax.plot(x, values, "k*", ms=9, label="best OpenCV")
        ax.plot(x, [target_ratio * v for v in values], "k_", ms=14, label=f"{target_ratio}x best OpenCV")
        ax.plot(
            x, [summaries[c][crb] or np.nan for c in keys], "rx", label="median error at the Cramer-Rao bound"
        )
        ax.set_yscale("log")
        ax.set_ylabel(f"median error, {unit}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8, ncol=3)
    nees = [summaries[c]["methods"][DEFAULT_METHOD].get("mean_nees") or np.nan for c in keys]
    axes[2].bar(x, nees, color="tab:blue")
    axes[2].axhspan(*nees_range, color="tab:green", alpha=0.2, label=f"acceptance {list(nees_range)}")
    axes[2].set_yscale("log")
    axes[2].set_ylabel(f"{DEFAULT_METHOD} mean NEES")
    axes[2].legend(fontsize=8)
    axes[2].set_xticks(x, keys, rotation=35, ha="right", fontsize=8)
    fig.suptitle("robustness: median error per case (log scale)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

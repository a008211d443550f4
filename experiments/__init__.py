"""hec: eye-in-hand calibration of a camera on a robot's flange, proven against a simulated cell.

The public API is hec.api, its names here: ``hec.import_dataset``, ``hec.load_dataset``,
``hec.detect``, ``hec.calibrate``, ``hec.write_report``, ``hec.verdict``, ``hec.findings``,
``hec.save_calibration``, ``hec.verify``, ``hec.export``, ``hec.plan``, their result types and their
errors (loaded on first use, so that the command line starts fast). The library is
``hec.estimator`` (detection, estimation, file formats), the simulated cell ``hec.sim`` (extra
``hec[sim]``) and the real cell ``hec.hardware`` (extras ``hec[ur]`` and ``hec[realsense]``); the
``hec`` command line is ``hec.cli``.
"""

from __future__ import annotations

from hec.support.version import VERSION as __version__

API = (
    "Calibration",
    "Dataset",
    "DatasetImportError",
    "ExportError",
    "ExportResult",
    "ImportOptions",
    "ImportResult",
    "PlanError",
    "Verdict",
    "VerifyResult",
    "ViewPlan",
    "calibrate",
    "detect",
    "export",
    "findings",
    "import_dataset",
    "load_dataset",
    "plan",
    "save_calibration",
    "verdict",
    "verify",
    "write_report",
)
__all__ = ["__version__", *API]


def __getattr__(name: str) -> object:
    """hec.api's names, imported when first asked for."""
    if name in API:
        from hec import api

        return getattr(api, name)
    raise AttributeError(f"module 'hec' has no attribute {name!r}")

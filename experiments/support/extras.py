"""The optional parts of hec and the libraries behind them: a command that needs a missing one says
which extra to install (``pip install 'hec[sim]'``) instead of failing with Python's own message."""

from __future__ import annotations

# The importable name of each optional library -> the extra that installs it.
EXTRA_OF_MODULE = {
    "mujoco": "sim",
    "numba": "sim",
    "pyrealsense2": "realsense",
    "rtde_control": "ur",
    "rtde_receive": "ur",
    "dask": "dask",
    "distributed": "dask",
}
WHAT_EXTRA_ADDS = {
    "sim": "the simulated cell",
    "realsense": "the RealSense camera",
    "ur": "the UR arm",
    "dask": "sweeps on a Dask cluster",
}


def missing_extra_message(exc: ModuleNotFoundError, command: str | None) -> str | None:
    """One line naming the extra that installs the missing module, or None when the module is not
    one of hec's optional libraries (a broken installation, reported as it is)."""
    top = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(top)
    if extra is None:
        return None
    who = f"hec {command}" if command else "hec"
    return (
        f"{who} needs {WHAT_EXTRA_ADDS[extra]} ({top} is not installed): "
        f"pip install 'hec[{extra}]' (or 'hec[all]' for every optional part)"
    )

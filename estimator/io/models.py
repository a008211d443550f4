"""The shipped models/ folder: MJCF, board definitions, scenarios, sweeps and cell files."""

from __future__ import annotations

from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"


def models_dir() -> Path:
    """The models/ folder, in a source checkout or an installed wheel."""
    if MODELS_DIR.is_dir():
        return MODELS_DIR
    from importlib.resources import files

    # hec_models is a namespace package: ask for a file in it to get a real folder.
    return Path(str(files("hec_models").joinpath("cell.xml"))).parent

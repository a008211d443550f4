"""The shipped models/ folder: MJCF, board definitions, scenarios, sweeps and cell files."""

from __future__ import annotations

from pathlib import Path

# models/ sits two folders above this file both in a source checkout (models/ beside estimator/)
# and in an installed wheel (hec/models beside hec/estimator).
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"


def models_dir() -> Path:
    """The models/ folder, in a source checkout or an installed wheel."""
    return MODELS_DIR

"""Command-line value types whose errors name the option (argparse adds 'argument --NAME:'), and options
shared by commands."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

DPI_RANGE = (72.0, 2400.0)


def seed(text: str) -> int:
    """A noise seed: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value


SIGMA_MAX = 1e4


def non_negative(text: str) -> float:
    """A 1-sigma, 0 to SIGMA_MAX (mm or degrees: past any arm's error, and far from overflowing)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    if value > SIGMA_MAX:
        raise argparse.ArgumentTypeError(f"must be at most {SIGMA_MAX:g}, got {text!r}")
    return value


def positive(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}")
    return value


def dpi(text: str) -> float:
    """A print resolution in dots per inch, within DPI_RANGE."""
    lo, hi = DPI_RANGE
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of dots per inch, got {text!r}") from None
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"must be {lo:g} to {hi:g} dots per inch, got {text!r}")
    return value


def add_scenario(parser: argparse.ArgumentParser) -> None:
    """--scenario: a simulated cell's scenario TOML, or a name in models/scenarios/."""
    parser.add_argument(
        "--scenario",
        type=Path,
        help="scenario TOML file, or a name in models/scenarios/ (realistic); default: the ideal cell",
    )

"""The parameters a sweep can vary (each one a column of the result rows, named as here), and
the fidelities they apply to. No simulator imports: the row schema and the report use them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hec.estimator.common.setups import SETUPS
from hec.estimator.geometry.waypoints import PAPER_OFFSETS_M, ROTATION_RICH_VIEWS

MEASUREMENTS, RENDER = "measurements", "render"
FIDELITIES = (MEASUREMENTS, RENDER)
BOTH = FIDELITIES
TRAJECTORIES = ("rotation-rich", "paper", "random")
MOUNTS = ("fixed", "random")
# Views of the full trajectories; a random trajectory has as many as the rotation-rich one by default.
FULL_VIEWS = {"rotation-rich": len(ROTATION_RICH_VIEWS), "paper": len(PAPER_OFFSETS_M), "random": 17}
MIN_WAYPOINTS = 3
# The model-error sections of a scenario (hec.sim.scenario.ModelErrors) an error_sources value names.
ERROR_SOURCES = ("arm", "intrinsics", "lens", "depth", "board", "image")


def error_source_set(value: str) -> tuple[str, ...]:
    """The sections an error_sources value switches on: "none", "all", or names joined by "+"
    ("arm+depth"), in ERROR_SOURCES order; ValueError for anything else."""
    if value == "none":
        return ()
    if value == "all":
        return ERROR_SOURCES
    names = value.split("+")
    if not names or any(n not in ERROR_SOURCES for n in names):
        raise ValueError(f"unknown error source in {value!r}")
    return tuple(n for n in ERROR_SOURCES if n in names)


def error_sources_name(enabled: tuple[str, ...]) -> str:
    """The error_sources value of a set of enabled sections."""
    if not enabled:
        return "none"
    return "all" if set(enabled) == set(ERROR_SOURCES) else "+".join(n for n in ERROR_SOURCES if n in enabled)


def _valid_error_sources(value: Any) -> bool:
    if not isinstance(value, str):
        return False
    try:
        error_source_set(value)
    except ValueError:
        return False
    return True


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and v == v and abs(v) != float("inf")


@dataclass(frozen=True)
class Parameter:
    """A sweep parameter: its row type, the fidelities it applies to, what values it takes."""

    name: str
    kind: type
    fidelities: tuple[str, ...]
    expected: str
    valid: Callable[[Any], bool]
    doc: str


def _float(name: str, fidelities: tuple[str, ...], lo: float | None, strict: bool, doc: str) -> Parameter:
    if lo is None:
        return Parameter(name, float, fidelities, "a number", _is_number, doc)
    expected = f"a number {'>' if strict else '>='} {lo:g}"
    return Parameter(
        name, float, fidelities, expected, lambda v: _is_number(v) and (v > lo if strict else v >= lo), doc
    )


PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        _float(
            "pixel_sigma_px",
            (MEASUREMENTS,),
            0.0,
            True,
            "corner noise per pixel coordinate, pixels (default 0.3); at render fidelity the image "
            "noise is rgb_sigma_grey and the detector's corner noise follows from it",
        ),
        _float(
            "rgb_sigma_grey",
            (RENDER,),
            0.0,
            False,
            "additive Gaussian image noise, 8-bit grey levels (scenario noise.rgb.sigma)",
        ),
        _float(
            "depth_subpixel",
            BOTH,
            0.0,
            False,
            "stereo disparity error, pixels (scenario noise.depth.subpixel)",
        ),
        _float("depth_bias_scale", BOTH, 0.0, True, "depth scale error: z_measured = scale * z + offset"),
        _float("depth_bias_offset_mm", BOTH, None, False, "depth offset, mm"),
        _float("robot_translation_sigma_mm", BOTH, 0.0, False, "reported flange position noise per axis, mm"),
        _float(
            "robot_rotation_sigma_deg", BOTH, 0.0, False, "reported flange rotation noise per axis, degrees"
        ),
        Parameter(
            "waypoints",
            int,
            BOTH,
            f"an integer >= {MIN_WAYPOINTS}",
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= MIN_WAYPOINTS,
            "the first N views of the trajectory (random: N views); default all "
            f"({', '.join(f'{k} {n}' for k, n in FULL_VIEWS.items())})",
        ),
        Parameter(
            "trajectory",
            str,
            BOTH,
            f"one of {', '.join(map(repr, TRAJECTORIES))}",
            lambda v: v in TRAJECTORIES,
            "rotation-rich (tilted and rolled views, the default), paper (translation only), random "
            "(views of the board centre, tilt 10-35 deg, any azimuth, roll +-30 deg, 0.9-1.2 x distance_m)",
        ),
        Parameter(
            "error_sources",
            str,
            (RENDER,),
            f"'none', 'all' or names from {', '.join(ERROR_SOURCES)} joined by '+'",
            _valid_error_sources,
            "the scenario's model-error sections ([errors.*]) switched on, at the scenario's "
            "magnitudes, the others off (default: those the scenario has on)",
        ),
        _float(
            "error_scale",
            (RENDER,),
            0.0,
            False,
            "every systematic error of the cell multiplied by this (default 1): the enabled model-error "
            "sections' magnitudes (arm offsets, lengths, twists; intrinsics; the lens' departure from "
            "its reported coefficients; depth registration; print scale, sag, placement) and the depth "
            "bias's departure from exact (the depth_bias_* columns are its 1x values)",
        ),
        Parameter(
            "board",
            str,
            (RENDER,),
            "a board name in models/boards/ or a board file relative to the scenario",
            lambda v: isinstance(v, str) and v != "",
            "the calibration target (scenario board.definition): any kind, for example hec_8qr, "
            "charuco_10x5, chessboard_10x5, aprilgrid_6x3",
        ),
        Parameter(
            "mount",
            str,
            BOTH,
            f"one of {', '.join(map(repr, MOUNTS))}",
            lambda v: v in MOUNTS,
            "fixed: the scenario's T_flange_cam (eye-to-hand: its T_base_cam); random: a new one per "
            "trial near it (up to 50 mm, ~20 deg)",
        ),
        Parameter(
            "setup",
            str,
            BOTH,
            f"one of {', '.join(map(repr, SETUPS))}",
            lambda v: v in SETUPS,
            "eye-in-hand (the camera on the flange, the board fixed) or eye-to-hand (the camera fixed "
            "at the scenario's stand, the board on the flange at its board_mount); default the scenario's",
        ),
    )
}


def parameter_columns(fidelity: str) -> list[str]:
    """The parameter columns of a fidelity's rows, in row order."""
    return [name for name, p in PARAMETERS.items() if fidelity in p.fidelities]

"""Sweep configuration files (TOML) for `hec sweep`: what is varied, at which fidelity, with which methods.

A sweep runs ``trials`` trials in every cell of a grid and every method on each trial::

    fidelity = "measurements"   # or "render"
    seed = 0                    # root seed; trial t of cell c draws from default_rng([seed, c, t])
    paired = false              # true: trial t draws from default_rng([seed, t]) in every cell
    trials = 100                # trials per cell
    methods = "all"             # or a list of names from hec.estimator.solve.methods.METHODS
    scenario = "cell.toml"      # optional scenario file (relative to this file); default: built-in

    [fixed]                     # one value each, the same in every cell
    mount = "random"

    [levels]                    # lists of one length, stepped together: level k takes every k-th value
    pixel_sigma_px = [0.15, 0.3, 0.6]
    robot_translation_sigma_mm = [0.05, 0.1, 0.2]

    [grid]                      # lists; every combination (with the levels as one more axis)
    trajectory = ["paper", "rotation-rich"]

Paired trials compare cells trial by trial: trial t of every cell draws the same mount (with
``mount = "random"``) and views, and the same noise wherever the cells consume random numbers
alike, so a difference between two cells is the parameters' and not the draws' (common random
numbers). Unpaired (the default, as before) every cell draws its own.

The cells are the levels (outermost) times the grid axes in file order. A parameter
not named takes its default: the scenario's value (noise, trajectory kind) or the one
listed in PARAMETERS. Every parameter is a column of the result rows, named as here.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, StrictStr, model_validator

from hec.estimator.io.schema import validated
from hec.estimator.io.tomlfile import Section, read_toml
from hec.estimator.targets.target import BoardDefinitionError
from hec.sim.model_errors import scaled_depth_bias, scaled_model_errors
from hec.sim.scenario import ModelErrors, Scenario, ScenarioError, load_scenario, scenario_from_dict
from hec.sweep.parameters import (
    ERROR_SOURCES,
    FULL_VIEWS,
    MEASUREMENTS,
    PARAMETERS,
    TRAJECTORIES,
    error_source_set,
    error_sources_name,
    parameter_columns,
)


class SweepConfigError(ValueError):
    """A sweep file cannot be read or has a bad key; the message names the file and the key."""


def scenario_defaults(scenario: Scenario) -> dict[str, Any]:
    """Each parameter's value in a scenario (waypoints None: the whole trajectory)."""
    noise = scenario.noise
    bias = noise.depth_bias
    robot = noise.robot_pose
    kind = scenario.trajectory.kind
    return {
        "pixel_sigma_px": 0.3,
        "rgb_sigma_grey": noise.rgb.sigma if noise.rgb.enabled else 0.0,
        "depth_subpixel": noise.depth.subpixel if noise.depth.enabled else 0.0,
        "depth_bias_scale": bias.scale if bias.enabled else 1.0,
        "depth_bias_offset_mm": 1e3 * bias.offset_m if bias.enabled else 0.0,
        "robot_translation_sigma_mm": 1e3 * robot.translation_sigma_m if robot.enabled else 0.0,
        "robot_rotation_sigma_deg": robot.rotation_sigma_deg if robot.enabled else 0.0,
        "waypoints": None,
        "trajectory": kind if kind in TRAJECTORIES else "rotation-rich",
        "error_sources": error_sources_name(
            tuple(n for n in ERROR_SOURCES if getattr(scenario.errors, n).enabled)
        ),
        "error_scale": 1.0,
        "mount": "fixed",
        "setup": scenario.setup,
        "board": scenario.board.definition,
    }


def cell_scenario(base: dict, base_dir: str, params: dict[str, Any], source: str = "sweep") -> Scenario:
    """The scenario of one cell: base (Scenario.to_dict()) with the cell's noise parameters.
    The trajectory and mount are set per trial (hec.sweep.runner)."""
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    noise = {k: dict(v) for k, v in data.get("noise", {}).items()}
    noise["depth"] = {**noise.get("depth", {}), "enabled": True, "subpixel": params["depth_subpixel"]}
    error_scale = params.get("error_scale", 1.0)
    scale, offset_m = scaled_depth_bias(
        params["depth_bias_scale"], 1e-3 * params["depth_bias_offset_mm"], error_scale
    )
    noise["depth_bias"] = {"enabled": scale != 1.0 or offset_m != 0.0, "scale": scale, "offset_m": offset_m}
    noise["robot_pose"] = {
        "enabled": True,
        "translation_sigma_m": 1e-3 * params["robot_translation_sigma_mm"],
        "rotation_sigma_deg": params["robot_rotation_sigma_deg"],
    }
    if "rgb_sigma_grey" in params:
        rgb = noise.get("rgb", {})
        on = rgb.get("enabled", True) or params["rgb_sigma_grey"] > 0
        noise["rgb"] = {**rgb, "enabled": on, "sigma": params["rgb_sigma_grey"]}
    data["noise"] = noise
    data["setup"] = params["setup"]
    if "board" in params:
        data["board"] = {**data.get("board", {}), "definition": params["board"]}
    if "error_sources" in params:
        on = error_source_set(params["error_sources"])
        errors = {k: dict(v) for k, v in data.get("errors", {}).items()}
        data["errors"] = {n: {**errors.get(n, {}), "enabled": n in on} for n in ERROR_SOURCES}
    if error_scale != 1.0:
        errors = scaled_model_errors(ModelErrors.model_validate(data.get("errors", {})), error_scale)
        data["errors"] = errors.model_dump(mode="json")
    return scenario_from_dict(data, source=source, base_dir=Path(base_dir))


@dataclass(frozen=True)
class Cell:
    """One grid cell: its index, id ('c03') and every parameter of the fidelity, resolved."""

    index: int
    id: str
    parameters: dict[str, Any]


@dataclass
class SweepConfig:
    """A validated sweep file. scenario: the base scenario (its dict and folder travel to the workers)."""

    path: Path
    fidelity: str
    seed: int
    paired: bool
    trials: int
    methods: list[str]
    scenario: Scenario
    scenario_file: str | None
    fixed: dict[str, Any]
    levels: dict[str, list]
    grid: dict[str, list]
    cells: list[Cell] = field(default_factory=list)

    @property
    def swept(self) -> list[str]:
        """The parameters that take more than one value, in column order."""
        varied = {k for k, v in {**self.levels, **self.grid}.items() if len(set(map(repr, v))) > 1}
        return [c for c in parameter_columns(self.fidelity) if c in varied]

    def to_dict(self) -> dict:
        """The resolved configuration (what sweep.json records and --resume compares)."""
        return {
            "fidelity": self.fidelity,
            "seed": self.seed,
            "paired": self.paired,
            "trials": self.trials,
            "methods": list(self.methods),
            "scenario_file": self.scenario_file,
            "scenario": self.scenario.to_dict(),
            "scenario_base_dir": str(Path(self.scenario.base_dir).resolve()),
            "fixed": dict(self.fixed),
            "levels": {k: list(v) for k, v in self.levels.items()},
            "grid": {k: list(v) for k, v in self.grid.items()},
            "swept": self.swept,
            "cells": [{"cell": c.id, "index": c.index, "parameters": c.parameters} for c in self.cells],
        }


def _error(path: Path, key: str, message: str) -> SweepConfigError:
    return SweepConfigError(f"{path}: key '{key}': {message}")


def _check_value(key: str, name: str, value: Any, fidelity: str) -> None:
    """A ValueError naming key unless value is one parameter name takes at fidelity."""
    if name not in PARAMETERS:
        raise ValueError(f"key '{key}': unknown parameter; expected one of {', '.join(PARAMETERS)}")
    p = PARAMETERS[name]
    if fidelity not in p.fidelities:
        other = "rgb_sigma_grey (grey levels)" if name == "pixel_sigma_px" else "pixel_sigma_px"
        raise ValueError(
            f"key '{key}': applies to fidelity '{p.fidelities[0]}' only; at '{fidelity}' use {other} instead"
        )
    if not p.valid(value):
        raise ValueError(f"key '{key}': expected {p.expected}, got {value!r}")


def _methods(value: str | list[str]) -> list[str]:
    """A sweep file's 'methods' as a list of names; a ValueError naming the bad entry."""
    from hec.estimator.solve.methods import METHODS

    if value == "all":
        return list(METHODS)
    names = [value] if isinstance(value, str) else value
    for i, name in enumerate(names):
        if name not in METHODS:
            raise ValueError(f"key 'methods[{i}]': unknown method {name!r}; choose from {', '.join(METHODS)}")
    if len(set(names)) != len(names):
        raise ValueError("key 'methods': a method is listed twice")
    return list(names)


Values = Annotated[list[Any], Field(min_length=1)]
_TABLE = "should be a table of parameter = value"
_AXIS = "should be a table of parameter = [values, ...], each list non-empty"


class SweepFile(Section):
    """A sweep file's keys (module doc); the parameters' values are checked against PARAMETERS."""

    fidelity: Literal["measurements", "render"] = Field(
        MEASUREMENTS, description="should be 'measurements' or 'render'"
    )
    seed: int = Field(0, strict=True, ge=0, description="should be an integer >= 0")
    paired: bool = Field(False, strict=True, description="should be true or false")
    trials: int = Field(1, strict=True, ge=1, description="should be an integer >= 1")
    methods: str | Annotated[list[StrictStr], Field(min_length=1)] = Field(
        "all", description='should be "all" or a list of method names'
    )
    scenario: StrictStr | None = Field(None, description="should be a file name")
    fixed: dict[str, Any] = Field({}, description=_TABLE)
    levels: dict[str, Values] = Field({}, description=_AXIS)
    grid: dict[str, Values] = Field({}, description=_AXIS)

    @model_validator(mode="after")
    def _values_known(self) -> SweepFile:
        _methods(self.methods)
        for k, v in self.fixed.items():
            _check_value(f"fixed.{k}", k, v, self.fidelity)
        for name in ("levels", "grid"):
            for k, values in getattr(self, name).items():
                for i, v in enumerate(values):
                    _check_value(f"{name}.{k}[{i}]", k, v, self.fidelity)
        lengths = {k: len(v) for k, v in self.levels.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"key 'levels': every list must have the same length, got {lengths}")
        seen: dict[str, str] = {}
        for section in ("fixed", "levels", "grid"):
            for k in getattr(self, section):
                if k in seen:
                    raise ValueError(f"key '{section}.{k}': already given in [{seen[k]}]")
                seen[k] = section
        return self


def load_config(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file and resolve its cells. Raises SweepConfigError."""
    path = Path(path)
    data = validated(
        SweepFile, read_toml(path, SweepConfigError, "sweep"), str(path), SweepConfigError, keys=True
    )
    try:
        scenario = load_scenario(None if data.scenario is None else path.parent / data.scenario)
    except ScenarioError as exc:
        raise SweepConfigError(f"{path}: key 'scenario': {exc}") from None

    def values(k: str, v: Any) -> Any:
        return float(v) if PARAMETERS[k].kind is float else v

    config = SweepConfig(
        path,
        data.fidelity,
        data.seed,
        data.paired,
        data.trials,
        _methods(data.methods),
        scenario,
        data.scenario,
        {k: values(k, v) for k, v in data.fixed.items()},
        {k: [values(k, v) for v in vs] for k, vs in data.levels.items()},
        {k: [values(k, v) for v in vs] for k, vs in data.grid.items()},
    )
    config.cells = _cells(config)
    return config


def _cells(config: SweepConfig) -> list[Cell]:
    """Every cell, parameters resolved, each checked against the scenario (and the trajectory length)."""
    defaults = scenario_defaults(config.scenario)
    columns = parameter_columns(config.fidelity)
    n_levels = len(next(iter(config.levels.values()))) if config.levels else 1
    level_sets = [{k: v[i] for k, v in config.levels.items()} for i in range(n_levels)]
    grid_sets = [
        dict(zip(config.grid, combo, strict=True)) for combo in itertools.product(*config.grid.values())
    ]
    base, base_dir = config.scenario.to_dict(), config.scenario.base_dir
    cells = []
    for index, (level, point) in enumerate(itertools.product(level_sets, grid_sets)):
        params = {**defaults, **config.fixed, **level, **point}
        given = params["waypoints"]
        full = FULL_VIEWS[params["trajectory"]]
        if given is None:
            params["waypoints"] = full
        elif params["trajectory"] != "random" and given > full:
            source = "fixed" if "waypoints" in config.fixed else "levels" if "waypoints" in level else "grid"
            raise _error(
                config.path,
                f"{source}.waypoints",
                f"{given} waypoints, but the {params['trajectory']} trajectory has {full} views",
            )
        params = {k: params[k] for k in columns}
        try:
            cell_scenario(base, base_dir, params, source=f"{config.path} (cell {index})").board_definition()
        except (ScenarioError, BoardDefinitionError) as exc:
            raise SweepConfigError(str(exc)) from None
        cells.append(Cell(index, f"c{index:02d}", params))
    return cells

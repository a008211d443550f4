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
from typing import Any

from hec.estimator.io.tomlfile import read_toml
from hec.estimator.targets.target import BoardDefinitionError
from hec.sim.model_errors import scaled_depth_bias, scaled_model_errors
from hec.sim.scenario import ModelErrors, Scenario, ScenarioError, load_scenario, scenario_from_dict
from hec.sweep.parameters import (
    ERROR_SOURCES,
    FIDELITIES,
    FULL_VIEWS,
    MEASUREMENTS,
    PARAMETERS,
    TRAJECTORIES,
    error_source_set,
    error_sources_name,
    parameter_columns,
)

TOP_LEVEL_KEYS = ("fidelity", "seed", "paired", "trials", "methods", "scenario", "fixed", "levels", "grid")


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


def _check_value(path: Path, key: str, name: str, value: Any, fidelity: str) -> Any:
    if name not in PARAMETERS:
        raise _error(path, key, f"unknown parameter; expected one of {', '.join(PARAMETERS)}")
    p = PARAMETERS[name]
    if fidelity not in p.fidelities:
        other = "rgb_sigma_grey (grey levels)" if name == "pixel_sigma_px" else "pixel_sigma_px"
        raise _error(
            path, key, f"applies to fidelity '{p.fidelities[0]}' only; at '{fidelity}' use {other} instead"
        )
    if not p.valid(value):
        raise _error(path, key, f"expected {p.expected}, got {value!r}")
    return float(value) if p.kind is float else value


def _section(path: Path, data: dict, name: str) -> dict:
    section = data.get(name, {})
    if not isinstance(section, dict):
        raise _error(path, name, "expected a table ([" + name + "])")
    return section


def _methods(path: Path, value: Any) -> list[str]:
    from hec.estimator.solve.methods import METHODS

    if value == "all":
        return list(METHODS)
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise _error(path, "methods", f'expected "all" or a list of method names, got {value!r}')
    for i, name in enumerate(value):
        if name not in METHODS:
            raise _error(path, f"methods[{i}]", f"unknown method {name!r}; choose from {', '.join(METHODS)}")
    if len(set(value)) != len(value):
        raise _error(path, "methods", "a method is listed twice")
    return list(value)


def _int(path: Path, data: dict, key: str, default: int, lo: int) -> int:
    value = data.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or value < lo:
        raise _error(path, key, f"expected an integer >= {lo}, got {value!r}")
    return value


def load_config(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file and resolve its cells. Raises SweepConfigError."""
    path = Path(path)
    data = read_toml(path, SweepConfigError, "sweep")
    for key in data:
        if key not in TOP_LEVEL_KEYS:
            raise _error(path, key, f"unknown key; expected one of {', '.join(TOP_LEVEL_KEYS)}")
    fidelity = data.get("fidelity", MEASUREMENTS)
    if fidelity not in FIDELITIES:
        raise _error(path, "fidelity", f"expected 'measurements' or 'render', got {fidelity!r}")
    seed = _int(path, data, "seed", 0, 0)
    paired = data.get("paired", False)
    if not isinstance(paired, bool):
        raise _error(path, "paired", f"expected true or false, got {paired!r}")
    trials = _int(path, data, "trials", 1, 1)
    methods = _methods(path, data.get("methods", "all"))
    scenario_file = data.get("scenario")
    if scenario_file is not None and not isinstance(scenario_file, str):
        raise _error(path, "scenario", f"expected a file name, got {scenario_file!r}")
    try:
        scenario = load_scenario(None if scenario_file is None else path.parent / scenario_file)
    except ScenarioError as exc:
        raise SweepConfigError(f"{path}: key 'scenario': {exc}") from None

    fixed = {
        k: _check_value(path, f"fixed.{k}", k, v, fidelity) for k, v in _section(path, data, "fixed").items()
    }
    axes: dict[str, dict[str, list]] = {}
    for name in ("levels", "grid"):
        axes[name] = {}
        for k, values in _section(path, data, name).items():
            if not isinstance(values, list) or not values:
                raise _error(path, f"{name}.{k}", f"expected a non-empty list of values, got {values!r}")
            axes[name][k] = [
                _check_value(path, f"{name}.{k}[{i}]", k, v, fidelity) for i, v in enumerate(values)
            ]
    lengths = {k: len(v) for k, v in axes["levels"].items()}
    if len(set(lengths.values())) > 1:
        raise _error(path, "levels", f"every list must have the same length, got {lengths}")
    seen: dict[str, str] = {}
    for section, names in (("fixed", fixed), ("levels", axes["levels"]), ("grid", axes["grid"])):
        for k in names:
            if k in seen:
                raise _error(path, f"{section}.{k}", f"already given in [{seen[k]}]")
            seen[k] = section

    config = SweepConfig(
        path,
        fidelity,
        seed,
        paired,
        trials,
        methods,
        scenario,
        scenario_file,
        fixed,
        axes["levels"],
        axes["grid"],
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

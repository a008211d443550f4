"""The regression baseline file (experiments/regress/baseline.json, format ``hec-regression-baseline``
version 1): its scenario, thresholds and recorded errors, read and checked, and how an update is written.

The rule (also written in the file's "rule" field), for translation (mm) and rotation (degrees) apart:

    bound = min(absolute, factor * recorded + floor)   when the baseline records the trial's seed
    bound = absolute                                    otherwise
    a trial fails when its error exceeds its bound, is not finite, or the pipeline raises.

The absolute bound (1 mm, 0.1 degree) is the project's promise. The relative bound catches a result
that got much worse than it was, long before it crosses the loose one. The same code on the same machine
reproduces the recorded figure bit for bit; other MuJoCo, OpenCV or BLAS builds can change a render
slightly, which the floor (0.05 mm, 0.005 degree) absorbs: a +-1 grey-level change of every colour pixel,
or a +-1 mm change of 1 % of the depth pixels, moved the estimate by at most 0.006 mm and 0.0005 degree,
a tenth of the floor. The factor 2 says what "much worse" means: twice the recorded error. It is wide
enough that a neutral change of the code, which re-draws the error within its spread (root-sum-square
Cramer-Rao bound of these views: 0.17 mm and 0.014 degree; RMS over 10 seeds: 0.17 mm and 0.018 degree),
seldom trips it, and it catches gross regressions: with the robot pose noise left out of the model, or
the principal point off by 1 px, 4 or 5 of the first 5 seeds fail while nearly all stay inside the loose
bound. Subtler changes are for the Monte-Carlo benchmark (experiments/bench/estimators.py).
"""

from __future__ import annotations

import math
import os
import platform
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

from hec.estimator.common.jsonfile import read_json_object

# sim (which picks the OpenGL backend) is imported where it is used.
if TYPE_CHECKING:
    from hec.sim.scenario import Scenario

FORMAT = "hec-regression-baseline"
VERSION = 1


DEFAULT_BASELINE = Path(__file__).with_name("baseline.json")
WAYPOINT_FILE = "waypoints.csv"
# A new baseline (`--update` on a missing file): ten of
# hec.estimator.geometry.waypoints.ROTATION_RICH_VIEWS, by index: tilts about the board's x and y
# axes and the diagonals, and rolls both ways, so every axis of the mount is observed. The baseline
# file stores the angles themselves (its views are all at the scenario's distance).
DEFAULT_VIEW_INDICES = (1, 3, 5, 7, 9, 10, 11, 12, 13, 14)
DEFAULT_SEED = 7  # tests/conftest.py TEST_SEED: the detector's floors were tuned on seed 0


DEFAULT_METHOD = "ekf"
DEFAULT_THRESHOLDS = {
    "translation_mm": {"absolute": 1.0, "factor": 2.0, "floor": 0.05},
    "rotation_deg": {"absolute": 0.1, "factor": 2.0, "floor": 0.005},
}


RULE = (
    "Per trial and per quantity (translation_mm, rotation_deg): bound = min(absolute, factor * recorded + "
    "floor) when 'recorded.trials' holds the trial's seed, else bound = absolute; the trial fails when its "
    "error exceeds the bound, is not finite, or the pipeline raises. absolute is the project's promise; "
    "factor * recorded + floor catches a result much worse than the one recorded. Same code, same machine: "
    "the recorded figure is reproduced bit for bit. The floor absorbs render differences between MuJoCo, "
    "OpenCV and BLAS builds (+-1 grey level on every colour pixel or +-1 mm on 1% of the depth pixels "
    "moved the estimate by at most 0.006 mm / 0.0005 deg, a tenth of the floor)."
)
VIEWS_CONVENTION = (
    "[tilt, azimuth, roll] degrees: the head-on view of the board centre tilted by tilt about the "
    "board-plane axis at azimuth from board x, then rolled about the optical axis "
    "(hec.estimator.geometry.waypoints.look_at_board), from scenario.settings.trajectory.distance_m"
)


QUANTITIES = (("translation_mm", "mm"), ("rotation_deg", "deg"))
PACKAGES = ("numpy", "scipy", "mujoco", "opencv-python-headless", "zxing-cpp", "pyzbar")


class BaselineError(ValueError):
    """A baseline file is missing, not JSON, or has a bad field; the message names the file and field."""


@dataclass(frozen=True)
class Threshold:
    """The bounds of one quantity, in its unit (mm or degrees): see the module docstring."""

    absolute: float
    factor: float
    floor: float

    def bound(self, recorded: float | None) -> tuple[float, str]:
        """The bound for a trial and which one it is ('absolute' or 'relative')."""
        if recorded is None:
            return self.absolute, "absolute"
        relative = self.factor * recorded + self.floor
        return (relative, "relative") if relative < self.absolute else (self.absolute, "absolute")


@dataclass(frozen=True)
class Measurement:
    """One trial: errors of the estimate against the ground truth (translation mm, geodesic rotation
    degrees), frames rendered of the views asked for; failure: why the pipeline stopped, else None."""

    seed: int
    translation_mm: float = math.nan
    rotation_deg: float = math.nan
    frames: int = 0
    failure: str | None = None

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "translation_mm": self.translation_mm,
            "rotation_deg": self.rotation_deg,
            "frames": self.frames,
        }


@dataclass(frozen=True)
class Baseline:
    """A loaded baseline file. views_deg: (tilt, azimuth, roll) degrees per waypoint.
    recorded: seed -> the measurement recorded for it. document: the file's JSON, kept for --update."""

    path: Path
    scenario: Scenario
    seed: int
    views_deg: tuple[tuple[float, float, float], ...]
    method: str
    thresholds: dict[str, Threshold]
    recorded: dict[int, Measurement]
    document: dict


def _field(data: dict, key: str, where: str, path: Path) -> object:
    if not isinstance(data, dict):
        raise BaselineError(f"{path}: field '{where}' must be a JSON object")
    if key not in data:
        raise BaselineError(f"{path}: missing field '{f'{where}.' if where else ''}{key}'")
    return data[key]


def _number(value: object, name: str, path: Path, minimum: float | None = 0.0) -> float:
    """A finite JSON number >= minimum (any finite number when minimum is None)."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (minimum is not None and value < minimum):
        expected = "a finite number" + ("" if minimum is None else f" >= {minimum:g}")
        raise BaselineError(f"{path}: field '{name}': expected {expected}, got {value!r}")
    return float(value)


def _seed(value: object, name: str, path: Path) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise BaselineError(f"{path}: field '{name}': expected an integer >= 0, got {value!r}")
    return value


def _views(value: object, path: Path) -> tuple[tuple[float, float, float], ...]:
    name = "scenario.views_deg"
    if not isinstance(value, list) or len(value) < 3:
        raise BaselineError(f"{path}: field '{name}': expected a list of at least 3 [tilt, azimuth, roll]")
    views = []
    for i, view in enumerate(value):
        if not isinstance(view, list) or len(view) != 3:
            raise BaselineError(f"{path}: field '{name}[{i}]': expected [tilt, azimuth, roll], got {view!r}")
        views.append(tuple(_number(v, f"{name}[{i}]", path, None) for v in view))
    return tuple(views)


def _scenario(section: dict, path: Path) -> Scenario:
    from hec.sim.scenario import ScenarioError, scenario_from_dict

    settings = _field(section, "settings", "scenario", path)
    if not isinstance(settings, dict):
        raise BaselineError(f"{path}: field 'scenario.settings' must be a JSON object (scenario keys)")
    trajectory = settings.get("trajectory", {})
    if not isinstance(trajectory, dict) or {"kind", "file"} & set(trajectory):
        raise BaselineError(
            f"{path}: field 'scenario.settings.trajectory' must be an object without 'kind' or 'file' "
            "(the waypoints are scenario.views_deg)"
        )
    try:
        # kind and file are placeholders here; trial_scenario sets the real waypoint file.
        data = settings | {"trajectory": trajectory | {"kind": "file", "file": WAYPOINT_FILE}}
        return scenario_from_dict(data, source=f"{path}: field 'scenario.settings'", base_dir=path.parent)
    except ScenarioError as exc:
        raise BaselineError(str(exc)) from None


def _thresholds(value: object, path: Path) -> dict[str, Threshold]:
    out = {}
    for quantity, _ in QUANTITIES:
        spec = _field(value, quantity, "thresholds", path)
        where = f"thresholds.{quantity}"
        out[quantity] = Threshold(
            absolute=_number(_field(spec, "absolute", where, path), f"{where}.absolute", path, 1e-12),
            factor=_number(_field(spec, "factor", where, path), f"{where}.factor", path, 1.0),
            floor=_number(_field(spec, "floor", where, path), f"{where}.floor", path),
        )
    return out


def _recorded(value: object, path: Path) -> dict[int, Measurement]:
    trials = _field(value, "trials", "recorded", path)
    if not isinstance(trials, list):
        raise BaselineError(f"{path}: field 'recorded.trials' must be a list")
    out: dict[int, Measurement] = {}
    for i, trial in enumerate(trials):
        where = f"recorded.trials[{i}]"
        s = _seed(_field(trial, "seed", where, path), f"{where}.seed", path)
        if s in out:
            raise BaselineError(f"{path}: field '{where}.seed': seed {s} is recorded twice")
        values = {q: _number(_field(trial, q, where, path), f"{where}.{q}", path) for q, _ in QUANTITIES}
        frames = int(_number(trial.get("frames", 0), f"{where}.frames", path))
        out[s] = Measurement(s, values["translation_mm"], values["rotation_deg"], frames)
    return out


def baseline_from_document(data: dict, path: Path, require_record: bool = True) -> Baseline:
    """Check a baseline document read from path; raises BaselineError naming the file and the field.
    require_record: the baseline seed must have a recorded figure (not so for a new baseline)."""
    from hec.estimator.solve.methods import METHODS

    if data.get("format") != FORMAT or data.get("version") != VERSION:
        raise BaselineError(
            f"{path}: fields 'format' and 'version': expected {FORMAT!r} version {VERSION}, "
            f"got {data.get('format')!r} version {data.get('version')!r}"
        )
    section = _field(data, "scenario", "", path)
    seed = _seed(_field(section, "seed", "scenario", path), "scenario.seed", path)
    method = _field(data, "method", "", path)
    if method not in METHODS:
        raise BaselineError(f"{path}: field 'method': expected one of {', '.join(METHODS)}, got {method!r}")
    recorded = _recorded(_field(data, "recorded", "", path), path)
    if require_record and seed not in recorded:
        raise BaselineError(
            f"{path}: field 'recorded.trials': no figure for the baseline seed {seed} "
            "(run hec regress --update to record one)"
        )
    return Baseline(
        path=path,
        scenario=_scenario(section, path),
        seed=seed,
        views_deg=_views(_field(section, "views_deg", "scenario", path), path),
        method=method,
        thresholds=_thresholds(_field(data, "thresholds", "", path), path),
        recorded=recorded,
        document=data,
    )


def load_baseline(path: Path) -> Baseline:
    """Read and check a baseline file; raises BaselineError naming the file and the field."""
    data = read_json_object(path, BaselineError, "baseline file missing (give --baseline FILE)")
    return baseline_from_document(data, path)


def new_baseline_document() -> dict:
    """The document of a new baseline: the default scenario, the DEFAULT_VIEW_INDICES views, DEFAULT_SEED,
    ekf and DEFAULT_THRESHOLDS, with nothing recorded yet."""
    from hec.estimator.geometry.waypoints import ROTATION_RICH_VIEWS
    from hec.sim.scenario import Scenario

    settings = Scenario().to_dict()
    del settings["seed"]
    settings["trajectory"] = {k: v for k, v in settings["trajectory"].items() if k not in ("kind", "file")}
    return {
        "format": FORMAT,
        "version": VERSION,
        "description": (
            "Regression baseline of the whole pipeline (render, detect, calibrate) on a small fixed "
            "scenario: tests/test_regression.py runs its seed, `hec regress --trials N` the seeds "
            "seed .. seed + N - 1"
        ),
        "scenario": {
            "seed": DEFAULT_SEED,
            "views_deg": [list(ROTATION_RICH_VIEWS[i][:3]) for i in DEFAULT_VIEW_INDICES],
            "views_convention": VIEWS_CONVENTION,
            "settings": settings,
        },
        "method": DEFAULT_METHOD,
        "rule": RULE,
        "thresholds": DEFAULT_THRESHOLDS,
        "recorded": {"trials": []},
    }


def environment() -> dict:
    """Python, platform, OpenGL backend and the versions of the packages that shape the figures."""

    def version(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "not installed"

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "mujoco_gl": os.environ.get("MUJOCO_GL"),
        **{name: version(name) for name in PACKAGES},
    }


def environment_changes(recorded: dict, current: dict) -> list[str]:
    """'name: recorded -> now' for each entry of the environment that differs."""
    return [
        f"{name}: {recorded.get(name)} -> {value}"
        for name, value in current.items()
        if name in recorded and recorded[name] != value
    ]


def updated_document(baseline_document: dict, measurements: list[Measurement], command: str) -> dict:
    """The baseline document with 'recorded' replaced by these measurements, now, and this environment."""
    return baseline_document | {
        "rule": RULE,
        "recorded": {
            "set_at": datetime.now(UTC).isoformat(timespec="seconds"),
            "command": command,
            "environment": environment(),
            "trials": [m.to_dict() for m in measurements],
        },
    }


def describe_update(old: dict[int, Measurement], new: list[Measurement]) -> list[str]:
    """Per seed: the recorded figures before and after, added, or dropped."""
    lines = []
    for m in new:
        before = old.get(m.seed)
        if before is None:
            lines.append(f"seed {m.seed}: new, {m.translation_mm:.5f} mm, {m.rotation_deg:.6f} deg")
            continue
        same = (before.translation_mm, before.rotation_deg) == (m.translation_mm, m.rotation_deg)
        lines.append(
            f"seed {m.seed}: {before.translation_mm:.5f} -> {m.translation_mm:.5f} mm, "
            f"{before.rotation_deg:.6f} -> {m.rotation_deg:.6f} deg{' (same)' if same else ''}"
        )
    kept = {m.seed for m in new}
    first = min(kept, default=0)
    lines += [
        f"seed {s}: dropped (not run this time; --trials {s - first + 1} --update would record it)"
        for s in sorted(old)
        if s not in kept
    ]
    return lines

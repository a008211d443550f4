"""An arm's kinematics for an import: a known arm by name (hec.estimator.geometry.kinematics.ARMS)
or a classic DH table in a file, TOML, YAML or JSON::

    name = "my_arm"                                  # optional; the file's name without suffix
    d = [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]   # metres, joints 1..6
    a = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]        # metres
    alpha = [1.5707963, 0.0, 0.0, 1.5707963, -1.5707963, 0.0]  # radians
    theta_offset = [0, 0, 0, 0, 0, 0]                # optional, radians added to each joint angle

Frames as UR's: DH frame 0 is the base, DH frame 6 the flange.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import yaml

from hec.estimator.geometry.kinematics import ARMS, URKinematics, arm_from_dict
from hec.estimator.io.tomlfile import tomllib


class ArmFileError(ValueError):
    """An arm that cannot be read; the message names the file and the field."""


def read_arm(spec: str | Path) -> URKinematics:
    """The arm named spec (a key of ARMS) or the DH table in the file spec (module doc)."""
    if str(spec) in ARMS:
        return ARMS[str(spec)]
    path = Path(spec)
    if not path.is_file():
        raise ArmFileError(
            f"{spec}: neither a known arm ({', '.join(ARMS)}) nor a DH table file (TOML, YAML or JSON)"
        )
    text = path.read_text(errors="replace")
    try:
        if path.suffix.lower() == ".toml":
            data = tomllib.loads(text)
        elif path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:  # TOMLDecodeError and JSONDecodeError are ValueErrors
        raise ArmFileError(f"{path}: not valid {path.suffix.lstrip('.').upper() or 'YAML'} ({exc})") from None
    if not isinstance(data, dict):
        raise ArmFileError(f"{path}: expected the fields d, a and alpha (module doc)")
    unknown = sorted(set(data) - {"name", "d", "a", "alpha", "theta_offset"})
    if unknown:
        raise ArmFileError(
            f"{path}: unknown field '{unknown[0]}'; a DH table has name, d, a, alpha, theta_offset"
        )
    rows = {key: _six(data, key, path) for key in ("d", "a", "alpha")}
    rows["theta_offset"] = _six(data, "theta_offset", path) if "theta_offset" in data else (0.0,) * 6
    return arm_from_dict(str(data.get("name", path.stem)), rows)


def _six(data: dict, key: str, path: Path) -> tuple[float, ...]:
    value = data.get(key)
    unit = "radians" if key in ("alpha", "theta_offset") else "metres"
    if (
        not isinstance(value, list)
        or len(value) != 6
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in value)
    ):
        raise ArmFileError(f"{path}: field '{key}' should be 6 finite numbers ({unit}), got {value!r}")
    return tuple(float(v) for v in value)

"""Reading JSON and YAML files whose errors name the file."""

from __future__ import annotations

import json
from pathlib import Path

import yaml


def read_text(path: Path, error: type[Exception]) -> str:
    """path's text (UTF-8, a byte-order mark dropped); raises error naming the file when it holds
    bytes that are not text (an image or a binary file given by mistake)."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); is it the file you meant?"
        ) from None


def read_json_object(path: Path, error: type[Exception], missing: str = "file missing") -> dict:
    """The JSON object in ``path``; raises ``error`` naming the file when it is
    missing (with the words ``missing``), not JSON, or not an object."""
    try:
        data = json.loads(read_text(path, error))
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a JSON object")
    return data


def read_yaml_object(path: Path, error: type[Exception], missing: str = "file missing") -> dict:
    """The YAML mapping in ``path`` (JSON is YAML); raises ``error`` naming the file when it is
    missing (with the words ``missing``), not YAML, or not a mapping."""
    try:
        data = yaml.safe_load(read_text(path, error))
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a YAML mapping")
    return data


def first_difference(recorded: object, now: object, key: str) -> str | None:
    """Where two JSON values differ, in words ("'simulation.seed' was 7 and is now 8"), or None."""
    if isinstance(recorded, dict) and isinstance(now, dict):
        for k in sorted(recorded.keys() | now.keys()):
            difference = first_difference(recorded.get(k), now.get(k), f"{key}.{k}")
            if difference is not None:
                return difference
        return None
    return None if recorded == now else f"'{key}' was {recorded!r} and is now {now!r}"


def first_field_difference(recorded: dict, now: dict) -> str | None:
    """The first of now's keys whose value differs from recorded's, in words, or None (now's values
    compared as they would read back from JSON: tuples as lists)."""
    for key, value in now.items():
        difference = first_difference(recorded.get(key), json.loads(json.dumps(value)), key)
        if difference is not None:
            return difference
    return None

"""TOML settings files (scenarios, sweeps, cells): reading with errors that name the file,
and pydantic sections that reject unknown keys."""

from __future__ import annotations

import sys
from pathlib import Path

from pydantic import BaseModel, ConfigDict, ValidationError

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10 (ROS 2 Humble's): the same parser as a package
    import tomli as tomllib


class Section(BaseModel):
    """A table of a settings file: unknown keys are errors, numbers are finite, values are frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def read_toml(path: Path, error: type[Exception], kind: str) -> dict:
    """The table in the TOML file at path; raises ``error`` naming the file when it is
    missing, a folder, or not valid TOML. kind: what the file is, in words ("scenario")."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise error(f"{path}: {kind} file not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, expected a {kind} TOML file") from None
    except UnicodeDecodeError as exc:
        raise error(
            f"{path}: not a text file (byte {exc.start} is not UTF-8), expected a {kind} TOML file"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None


def validation_problems(exc: ValidationError, source: str) -> str:
    """One line per bad key of a TOML file read into a pydantic model: the file, the dotted
    key, what is wrong and the value given."""
    problems = []
    for err in exc.errors():
        key = ".".join(str(part) for part in err["loc"]) or "(top level)"
        message = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
        got = "" if err["type"] in ("extra_forbidden", "missing") else f" (got {err['input']!r})"
        problems.append(f"{source}: key '{key}': {message}{got}")
    return "\n".join(problems)

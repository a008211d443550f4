"""Declared file formats: pydantic models whose problems read as one line naming the file, the
field and what it expects.

A format's fields carry what they expect in their ``description``, worded to follow the field's
name ("should be an integer >= 1"); a problem then reads ``<file>: field 'tag_cols' should be an
integer >= 1, got 0`` (a field inside a list: ``markers[2].qr_mask must be 0-7 ..., got 8``).
A settings file (TOML) names them as keys instead: ``<file>: key 'trials': should be an
integer >= 1, got 0``. A validator's ValueError is the whole message after the file's name.
Numbers are checked strictly (no "3" for 3, no true for 1) through the types below; lists are
read into tuples.
"""

from __future__ import annotations

import types
import typing
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictStr, ValidationError

Integer = Annotated[int, Field(strict=True)]
Number = Annotated[float, Field(strict=True)]
Positive = Annotated[float, Field(strict=True, gt=0)]
Text = StrictStr
Flag = StrictBool
FormatT = TypeVar("FormatT", bound="FileFormat")


class FileFormat(BaseModel):
    """A file's content or one of its tables: numbers finite, unknown keys refused unless a
    format allows them (model_config extra)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def validated(
    model: type[FormatT], data: dict, source: str, error: type[Exception], keys: bool = False
) -> FormatT:
    """data read as ``model``; raises ``error`` with problem_line when it does not fit. keys: name
    fields as a settings file's keys (problem_line)."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise error(problem_line(exc, model, data, source, keys)) from None


def problem_line(
    exc: ValidationError, model: type[BaseModel], data: dict, source: str, keys: bool = False
) -> str:
    """The first problem of a validation as one line (module doc), with how many other fields have
    one. keys: name a field as a TOML settings file's key, ``key 'grid.pixel_sigma_px[1]':``."""
    errors = exc.errors()
    first = _problem(errors[0], model, data, source, keys)
    fields = {tuple(_field_at(err["loc"], model, data)[0]) for err in errors}
    return first if len(fields) == 1 else f"{first} (and {len(fields) - 1} more fields)"


def _problem(err: Any, model: type[BaseModel], data: dict, source: str, keys: bool) -> str:
    names, expected, value = _field_at(err["loc"], model, data)
    if not names:
        where = ""
    elif keys:
        where = f"key '{'.'.join(names)}':"
    else:
        where = f"field '{names[0]}'" if len(names) == 1 else ".".join(names)
    if err["type"] == "value_error":
        text = str(err["ctx"]["error"])
        return f"{source}: {text}" if not where else f"{source}: {where} {text}"
    if err["type"] == "extra_forbidden":
        if not keys:
            return f"{source}: {where} is not a field of this file"
        known = f"; expected one of {', '.join(model.model_fields)}" if len(names) == 1 else ""
        return f"{source}: {where} unknown key{known}"
    expected = expected or f"is wrong: {err['msg'][0].lower()}{err['msg'][1:]}"
    if err["type"] == "missing" and value is None:
        return f"{source}: {where} is missing; it {expected}"
    return f"{source}: {where} {expected}, got {value!r}"


def _field_at(loc: tuple, model: type[BaseModel] | None, data: object) -> tuple[list[str], str, object]:
    """The field a pydantic error location points into: its path (["markers[2]", "qr_mask"]),
    what it expects (its description) and the value the file gave (None when absent)."""
    names: list[str] = []
    expected = ""
    for part in loc:
        if isinstance(part, int) and names and model is not None and isinstance(data, list):
            names[-1] += f"[{part}]"
            data = data[part] if part < len(data) else None
            continue
        if not isinstance(part, str) or model is None or part not in model.model_fields:
            if isinstance(part, str) and not names:
                names.append(part)  # an unknown key, or a validator's
            break
        info = model.model_fields[part]
        names.append(part)
        expected = info.description or ""
        data = data.get(part) if isinstance(data, dict) else None
        model = _model_in(info.annotation)
    return names, expected, data


def _model_in(annotation: object) -> type[BaseModel] | None:
    """The pydantic model a field holds (itself, or in a list or an optional), else None."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (list, typing.Union, types.UnionType):
        return next((m for a in typing.get_args(annotation) if (m := _model_in(a))), None)
    return None

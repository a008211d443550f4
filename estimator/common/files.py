"""Writing result files so that a crash never leaves one half-written, and a failed write is an
error that names the file (a full disk's names none, a temporary file's the wrong one)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO


@contextlib.contextmanager
def errors_naming(path: Path) -> Iterator[None]:
    """Within: an OSError is raised again as one (of the same kind) about path."""
    try:
        yield
    except OSError as exc:
        if exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from exc


@contextlib.contextmanager
def open_text(path: Path, mode: str) -> Iterator[TextIO]:
    """open(path, mode, newline="") (for csv) whose errors, a full disk's too, name path."""
    with errors_naming(path), open(path, mode, newline="") as f:
        yield f


def write_atomic(path: Path, data: str | bytes) -> Path:
    """Write data (text or bytes) to path through a temporary sibling and a rename; on failure
    neither is left half-written and the error names path."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        with errors_naming(path):
            tmp.write_bytes(data.encode() if isinstance(data, str) else data)
            tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path

"""Writing result files so that a crash never leaves one half-written, and a failed write is an
error that names the file (a full disk's names none, a temporary file's the wrong one); an output
checked before the work (a folder that is missing or read-only, a folder given for a file, one of
the command's own inputs); and an operating system's error in hec's words: the file, what the system
said and what to do, on one line."""

from __future__ import annotations

import contextlib
import errno
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
    neither is left half-written and the error names path. A device, pipe or socket at path is
    refused, not replaced."""
    path = Path(path)
    refuse_special_file(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        with errors_naming(path):
            tmp.write_bytes(data.encode() if isinstance(data, str) else data)
            tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


# What to do about the operating system's errors a user meets (os_error_text).
_WHAT_TO_DO = {
    errno.EROFS: "the file system is read-only: write somewhere else",
    errno.ENOSPC: "the disk is full: free some space or write somewhere else",
    errno.EDQUOT: "the disk quota is used up: free some space or write somewhere else",
    errno.EACCES: "permission denied: write somewhere you may, or change the permissions",
    errno.EPERM: "not permitted: write somewhere you may, or change the permissions",
    errno.ENOENT: "no such file or folder: check the path (a folder to write in must exist)",
    errno.EISDIR: "it is a folder: give a file name",
    errno.ENOTDIR: "a part of the path is a file, not a folder: check the path",
    errno.ENAMETOOLONG: "the name is too long (at most 255 bytes a name): give a shorter one",
    errno.EEXIST: "it exists already: choose another name",
    errno.ENOTEMPTY: "the folder is not empty: choose another name",
}


def os_error_text(exc: OSError) -> str:
    """An OSError in hec's words, one line: 'FILE: what the system said; what to do' (Python's own
    '[Errno N] ...' says neither what nor what to do). An error without a number is its message."""
    if exc.errno is None or exc.strerror is None:
        return str(exc)
    name = "" if exc.filename is None else f"{exc.filename}: "
    return f"{name}{_strerror_and_hint(exc)}"


def _strerror_and_hint(exc: OSError) -> str:
    hint = _WHAT_TO_DO.get(exc.errno)
    return f"{exc.strerror}" + ("" if hint is None else f"; {hint}")


def refuse_special_file(path: Path) -> None:
    """FileExistsError when path is a device, a pipe or a socket (/dev/full, /dev/null): the rename
    of an atomic write would replace it with a file."""
    if path.exists() and not path.is_file() and not path.is_dir():
        raise FileExistsError(
            f"{path}: is a device, a pipe or a socket, not a file; give a file name (it is not replaced)"
        )


def check_output_file(path: Path, expected: str = "a file name") -> None:
    """Raise FileNotFoundError / IsADirectoryError / PermissionError now rather than after the work
    (a folder that does not exist, a folder given, one that cannot be written: read-only, full).
    expected: what path should be, in words, for the folder case."""
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(
            f"{path}: folder {path.parent} does not exist; create it or write somewhere else"
        )
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected {expected}")
    refuse_special_file(path)
    probe = path.with_name(f".{path.name}.probe-{os.getpid()}")
    try:
        probe.write_bytes(b"{}")
    except OSError as exc:
        with contextlib.suppress(OSError):  # a read-only file system refuses even this unlink
            probe.unlink()
        raise PermissionError(f"{path}: cannot write in {path.parent} ({_strerror_and_hint(exc)})") from None
    probe.unlink()


def same_file(a: Path, b: Path) -> bool:
    """Whether a and b are one file or folder (links and relative paths resolved)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def refuse_writing_over_inputs(out: Path, inputs: dict[str, Path | None], option: str = "--out") -> None:
    """ValueError when the output out is one of the command's inputs (named by what they are), or
    holds one (a folder that would replace a source): an output never replaces what it reads."""
    out = Path(out)
    for what, source in inputs.items():
        if source is None:
            continue
        if same_file(out, source):
            raise ValueError(f"{option} {out}: is the {what} this command reads; give another {option}")
        if Path(source).resolve().is_relative_to(out.resolve()):
            raise ValueError(
                f"{option} {out}: holds the {what} this command reads ({source}); give a {option} outside it"
            )

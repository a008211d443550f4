"""A folder in use by one process: a lock file holding its PID, and partial folders of dead processes.

A lock whose process no longer runs (killed, crashed, the machine restarted) is stale: the next
process takes it over and says so. Temporary folders named ``.NAME.partial-PID`` are recognised the
same way: one whose process is gone is a leftover to remove.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from hec.estimator.common.files import errors_naming

LOCK_FILE = ".hec-lock"
_PARTIAL = re.compile(r"\.partial-(\d+)$")


class FolderLockedError(RuntimeError):
    """Another running process holds the folder's lock."""


def process_alive(pid: int) -> bool:
    """Whether a process with this PID runs (zombies of this machine count as gone)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state != "Z"


def _holder(path: Path) -> int | None:
    """The PID written in a lock file, or None when it holds no number."""
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return None
    return int(text) if text.isdigit() else None


def acquire_lock(folder: Path, what: str) -> str | None:
    """Lock folder for this process (folder/.hec-lock with its PID). Raises FolderLockedError when a
    running process holds it; takes over a stale lock and returns a sentence saying so (else None).
    what: what the lock protects, for the messages ("a recording")."""
    path = Path(folder) / LOCK_FILE
    note = None
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid = _holder(path)
            if pid == os.getpid():
                return note
            if pid is not None and process_alive(pid):
                raise FolderLockedError(
                    f"{folder}: {what} is in progress there (process {pid}, lock file {path}); wait for it "
                    "to end or stop it first"
                ) from None
            path.unlink(missing_ok=True)
            note = f"removed a stale lock of {what} by process {pid}, which no longer runs ({path})"
            continue
        try:
            with errors_naming(path), os.fdopen(fd, "w") as f:
                f.write(f"{os.getpid()}\n")
        except OSError:  # a full disk: no lock without its PID is left
            path.unlink(missing_ok=True)
            raise
        return note
    raise FolderLockedError(f"{folder}: another process took the lock {path} at the same moment")


def release_lock(folder: Path) -> None:
    """Remove folder's lock if this process holds it."""
    path = Path(folder) / LOCK_FILE
    if _holder(path) == os.getpid():
        path.unlink(missing_ok=True)


def _partials(target: Path) -> list[tuple[Path, int]]:
    """The .TARGET.partial-PID siblings of target of other processes than this one, with their PIDs."""
    found = []
    for partial in Path(target).parent.glob(f".{Path(target).name}.partial-*"):
        match = _PARTIAL.search(partial.name)
        if match and int(match[1]) != os.getpid():
            found.append((partial, int(match[1])))
    return found


def remove_dead_partials(target: Path) -> list[Path]:
    """Remove the .TARGET.partial-PID siblings of target whose process no longer runs (left by a
    killed run). Returns the folders removed."""
    removed = []
    for partial, pid in _partials(target):
        if not process_alive(pid):
            if partial.is_dir():
                shutil.rmtree(partial, ignore_errors=True)
            else:
                partial.unlink(missing_ok=True)
            removed.append(partial)
    return removed


def writers_running(target: Path) -> list[int]:
    """The PIDs of other running processes writing target (a live .TARGET.partial-PID sibling)."""
    return sorted(pid for _, pid in _partials(target) if process_alive(pid))

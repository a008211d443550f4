"""A table of faults over every verb, each case run through the real command line and put in one
class: clear (a one-line refusal naming the file or option), handled (the command did the right
thing), vague (a refusal that names nothing, or Python's own [Errno N] words), traceback, silent
(exit 0 where it had to refuse), lost (an input changed) or left behind (a file the failed run made).

The cases live in tests/fault_cases.py; tests/test_fault_table.py runs each as a test, and
`python -m tests.fault_table` runs them all and prints the count per class."""

from __future__ import annotations

import collections
import contextlib
import hashlib
import io
import subprocess
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from hec.cli import main as hec_main

CLASSES = ("clear", "handled", "vague", "traceback", "silent", "lost", "left behind")
# A case's build: (the shared inputs, an empty work folder) -> (argv, the words the refusal must
# hold, or None when the command must succeed).
Build = Callable[[dict[str, Path], Path], tuple[list[str], list[str] | None]]


@dataclass(frozen=True)
class Case:
    """One fault: its name, its build, and the file system its work folder is on (None: the test's
    own; 'ro' a read-only one, 'full' one with no room)."""

    name: str
    build: Build
    fs: str | None = None


def _digest(folder: Path) -> dict[str, str]:
    """Every file and folder under folder with its content's hash (folders: '/')."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p.relative_to(folder))] = "/" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@contextlib.contextmanager
def work_folder(where: Path, fs: str | None) -> Iterator[Path]:
    """where, made; with fs, a small tmpfs mounted there (read-only, or of 4 KiB: full at once)."""
    where.mkdir(parents=True)
    if fs is None:
        yield where
        return
    options = "size=4k,ro" if fs == "ro" else "size=4k"
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True
    ).returncode:
        raise PermissionError("cannot mount a tmpfs here (needs root)")
    try:
        if fs == "full":  # fill the one page, so the first write meets a full disk
            with contextlib.suppress(OSError):
                (where / ".fill").write_bytes(b"x" * 1_000_000)
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def run_case(case: Case, inputs: dict[str, Path], where: Path) -> tuple[str, str]:
    """Run one case in the folder where (made here): its class and what the command printed."""
    with work_folder(where, case.fs) as work:
        argv, words = case.build(inputs, work)
        before_inputs, before_work = _digest(inputs["root"]), _digest(work)
        out, err = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    code = hec_main(argv)
                except SystemExit as exc:  # argparse's own refusal (hec VERB: error: ...)
                    code = int(exc.code or 0)
        except BaseException:  # noqa: BLE001 - a traceback is what this class records
            return "traceback", traceback.format_exc()
        out, err = out.getvalue(), err.getvalue()
        text = f"exit {code}\n{out}{err}"
        if "Traceback (most recent call last)" in err:
            return "traceback", text
        after_work = _digest(work)
        if _digest(inputs["root"]) != before_inputs or any(
            after_work.get(k) != v for k, v in before_work.items()
        ):
            return "lost", text
        new = set(after_work) - set(before_work)
        if words is None:
            if code != 0:
                return "vague", text  # a refusal of input it had to take
            hidden = [n for n in new if any(part.startswith(".") for part in Path(n).parts)]
            return ("left behind", text) if hidden else ("handled", text)
        if code == 0:
            return "silent", text
        if new:
            return "left behind", text + f"\nleft: {sorted(new)}"
        last = err.strip().splitlines()[-1] if err.strip() else ""  # the refusal: one line, the last
        one_line = last.startswith("hec") and "error:" in last
        named = all(w in last for w in words)
        return ("clear" if one_line and named and "[Errno" not in last else "vague"), text


def main() -> int:
    """Run every case and print the count per class and the cases outside clear and handled."""
    from tests.fault_cases import CASES, build_inputs

    with tempfile.TemporaryDirectory() as tmp:
        inputs = build_inputs(Path(tmp) / "inputs")
        counts: collections.Counter[str] = collections.Counter()
        bad = []
        for case in CASES:
            try:
                kind, text = run_case(case, inputs, Path(tmp) / "work" / case.name)
            except PermissionError:
                kind, text = "skipped", "no tmpfs"
            counts[kind] += 1
            if kind not in ("clear", "handled", "skipped"):
                bad.append((case.name, kind, text))
    print(f"{len(CASES)} cases")
    for kind in (*CLASSES, "skipped"):
        print(f"  {kind:12s} {counts[kind]:4d}")
    for name, kind, text in bad:
        print(f"\n{name}: {kind}\n{text}")
    return 0 if not bad else 1


if __name__ == "__main__":
    sys.exit(main())

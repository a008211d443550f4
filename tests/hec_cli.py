"""Running the `hec` command line inside a test."""

from __future__ import annotations

import contextlib
import io

from experiments.cli import main


def run_hec(argv: list[str]) -> tuple[int, str, str]:
    """main(argv) with stdout and stderr captured (usable from module-scoped fixtures, unlike capsys):
    exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()

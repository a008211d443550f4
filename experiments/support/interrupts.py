"""Signals that stop a command: Ctrl-C (SIGINT), SIGTERM and SIGHUP (a batch system, `timeout`, a
closed terminal) alike. The first raises KeyboardInterrupt (Terminated for SIGTERM and SIGHUP), so the
command's clean-up runs and hec exits with 128 + the signal number; further ones are ignored until
the process has ended (hec says so once), so that a second Ctrl-C cannot cut the clean-up short.

Nothing heavy is imported here: hec.cli takes the signals before it imports the commands
(MuJoCo, OpenCV and SciPy load for seconds), so a signal during that is an interruption too.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
STILL_CLEANING = b"\nhec: still cleaning up, please wait\n"


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP: the command stops as on Ctrl-C, and hec exits with 128 + the signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum


def interrupted_exit_code(exc: KeyboardInterrupt) -> int:
    """128 + the signal that stopped the command (130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP)."""
    return 128 + (exc.signum if isinstance(exc, Terminated) else signal.SIGINT)


def _at_default(signum: int) -> bool:
    """Whether signum has its default disposition (Python's own KeyboardInterrupt for SIGINT): a
    signal the caller ignores (nohup's SIGHUP, a background job's SIGINT) stays ignored."""
    default = signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL
    return signal.getsignal(signum) is default


@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """Within: the first stop signal raises KeyboardInterrupt or Terminated; later ones, while the
    command cleans up, are ignored (said once on stderr). On the way out the handlers are restored,
    unless a signal came: then the process is ending and stop signals stay ignored (Python would
    give them back their default, killing, action before it tears its modules down, which takes a
    while). Only signals at their default disposition are taken, and in a thread other than the
    main one (main() called from a thread) none."""
    stopping = told = False

    def on_signal(signum: int, frame: object) -> None:
        nonlocal stopping, told
        if stopping:
            if not told:
                told = True
                with contextlib.suppress(OSError):  # no buffered stream here: the signal may cut a print
                    os.write(2, STILL_CLEANING)
            return
        stopping = True
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)

    replaced = {}
    with contextlib.suppress(ValueError):  # not the main thread
        for signum in STOP_SIGNALS:
            if _at_default(signum):
                replaced[signum] = signal.signal(signum, on_signal)
    try:
        yield
    finally:
        for signum, previous in replaced.items():
            signal.signal(signum, signal.SIG_IGN if stopping else previous)

"""The ``hec`` command line. It takes Ctrl-C, SIGTERM and SIGHUP (experiments.interrupts) before it
imports the commands, whose libraries load for seconds, so a signal while they load is an
interruption like any other: one line, exit code 128 + the signal number, no traceback."""

from __future__ import annotations

import sys

from experiments import interrupts


def main(argv: list[str] | None = None) -> int:
    """Run `hec ARGV` (default: the process's arguments); returns the exit code."""
    with interrupts.stop_signals():
        started = None
        try:
            from experiments import commands

            args = commands.build_parser().parse_args(argv)
            started = args.command
            return commands.run(args)
        except KeyboardInterrupt as exc:  # Ctrl-C, or Terminated, where the command has no own message
            what = f"; {started} did not finish" if started else " while starting; nothing done"
            print(f"\nhec: interrupted ({str(exc) or 'Ctrl-C'}){what}", file=sys.stderr)
            return interrupts.interrupted_exit_code(exc)


if __name__ == "__main__":
    sys.exit(main())

"""The ``hec`` command line. It takes Ctrl-C, SIGTERM and SIGHUP (hec.support.interrupts) before it
imports the commands, whose libraries load for seconds, so a signal while they load is an
interruption like any other: one line, exit code 128 + the signal number, no traceback."""

from __future__ import annotations

import sys

from hec.support import interrupts
from hec.support.extras import missing_extra_message


def main(argv: list[str] | None = None) -> int:
    """Run `hec ARGV` (default: the process's arguments); returns the exit code."""
    with interrupts.stop_signals():
        started = None
        try:
            from hec.commands import table as commands

            argv = sys.argv[1:] if argv is None else argv
            args = commands.build_parser(argv).parse_args(argv)
            started = args.command
            return commands.run(args)
        except KeyboardInterrupt as exc:  # Ctrl-C, or Terminated, where the command has no own message
            what = f"; {started} did not finish" if started else " while starting; nothing done"
            print(f"\nhec: interrupted ({str(exc) or 'Ctrl-C'}){what}", file=sys.stderr)
            return interrupts.interrupted_exit_code(exc)
        except ModuleNotFoundError as exc:  # an optional part (an extra) that is not installed
            message = missing_extra_message(exc, started)
            if message is None:
                raise
            print(f"hec: error: {message}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())

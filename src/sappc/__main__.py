"""The ``sappc`` command (``python -m sappc`` and the ``sappc`` script): Ctrl-C first, then the CLI.

Ctrl-C (SIGINT) anywhere in a command, the import of the command line and its libraries
included (about a second), ends it with one line on stderr and :data:`EXIT_INTERRUPTED`, after
the command has cleaned up (``sappc run`` stops every node it started and finalises the bag).
SIGINT is honoured even when the command was started with it ignored: a non-interactive shell
starts a background job (``sappc run ... &``) with SIGINT ignored, and that Ctrl-C would
otherwise be lost.  Nothing heavier than the standard library is imported before the handler is
in place, so only the interpreter's own start-up (tens of milliseconds) is left to the default
action (the process ends by SIGINT, which a shell reports as 130 too, before anything started).

The command's start-up runs with the garbage collector's thresholds raised
(:func:`gnc_common.collector.hold`; the command settles it, :func:`sappc.cli.main`).
"""

from __future__ import annotations

import gc
import signal
import sys
from collections.abc import Sequence

__all__ = ["EXIT_INTERRUPTED", "main"]

#: Exit status after Ctrl-C (128 + SIGINT), as shells report a process ended by SIGINT.
EXIT_INTERRUPTED = 128 + signal.SIGINT


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``sappc`` command (:func:`sappc.cli.main`); Ctrl-C: one line and :data:`EXIT_INTERRUPTED`."""
    signal.signal(signal.SIGINT, signal.default_int_handler)  # also when started with SIGINT ignored
    from gnc_common import collector

    collector.hold()  # the command's start-up (its imports, its kernels): settled by the command (sappc.cli.main)
    try:
        from sappc.cli import main as cli_main

        code = cli_main(argv)
        # The interpreter's teardown collects garbage over every object still alive (matplotlib's,
        # numpy's, the bag's: 0.1-0.3 s after a report); frozen, they are left to the process's end.
        # Atexit handlers and the closing of open files still run.
        gc.freeze()
        return code
    except KeyboardInterrupt as exc:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C cannot turn this line into a traceback
        if not exc.args:  # a command that already said why it stopped passes its line as the argument
            print("sappc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())

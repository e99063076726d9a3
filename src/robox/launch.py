"""The robox-cli entry point, kept free of heavy imports.

A Ctrl-C while Python is still importing the command line's modules would otherwise
end in a traceback, and output cut short by a closed pipe (`robox-cli status | head
-1`) in "Broken pipe": both end quietly here, as a shell tool's do.
"""

from __future__ import annotations

import os
import signal
import sys

EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE


def main() -> None:
    try:
        from robox.cli import cli

        status = cli.main(prog_name="robox-cli", standalone_mode=True)
    except KeyboardInterrupt:
        sys.stderr.write("robox-cli: error: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    except BrokenPipeError:
        quiet_exit_after_broken_pipe()
    sys.exit(status)


def quiet_exit_after_broken_pipe() -> None:
    """The reader of our output has gone: nothing more can be said to it, and Python's
    own flush of stdout at exit must not complain either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    sys.exit(EXIT_BROKEN_PIPE)

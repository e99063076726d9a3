"""The robox-cli entry point, kept free of heavy imports.

A Ctrl-C while Python is still importing the command line's modules would otherwise
end in a traceback, and output cut short by a closed pipe (`robox-cli status | head
-1`) in "Broken pipe": both end quietly here, as a shell tool's do. A SIGTERM (`kill`,
a service manager stopping a script) is taken as a Ctrl-C, where Python's default would
end the process on the spot: the command lets go of its port, removes its temporary
files and says where it stopped, as for a Ctrl-C (`sim serve` has its own handler).

The cyclic garbage collector is off while the command line and the command's module
are imported. Once the command's module is loaded (robox.cli calls start_up_over), what
the imports made is frozen (gc.freeze: the collector never looks at it again) and the
collector is turned back on for the command. The modules' classes, functions and
tables live as long as the process, yet the collector looked through them again and
again, at exit too: 27 million of the 236 million instructions of `status` to a served
printer (callgrind). The little garbage the imports leave is kept with them.
"""

from __future__ import annotations

import gc
import os
import signal
import sys

EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE


_collector_held = False  # main() turned the collector off for the start-up


def _terminated(_signal: int, _frame: object) -> None:
    raise KeyboardInterrupt


def main() -> None:
    global _collector_held
    if gc.isenabled():
        gc.disable()
        _collector_held = True
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:  # (an ignored one stays so)
        signal.signal(signal.SIGTERM, _terminated)
    try:
        from robox.cli import cli

        status = cli.main(prog_name="robox-cli", standalone_mode=True)
    except KeyboardInterrupt:
        sys.stderr.write("robox-cli: error: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    except BrokenPipeError:
        quiet_exit_after_broken_pipe()
    sys.exit(status)


def start_up_over() -> None:
    """The command's module is loaded: what the imports made is frozen and the collector
    back on, if main() turned it off (a program that runs the command line itself keeps
    its collector as it has it)."""
    global _collector_held
    if _collector_held:
        _collector_held = False
        gc.freeze()
        gc.enable()


def quiet_exit_after_broken_pipe() -> None:
    """The reader of our output has gone: nothing more can be said to it, and Python's
    own flush of stdout at exit must not complain either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    sys.exit(EXIT_BROKEN_PIPE)

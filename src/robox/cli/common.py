"""What every robox-cli command shares: error mapping, exit codes, output."""

from __future__ import annotations

import json
import sys

import click

from robox.errors import RoboxError, UsageError

EXIT_OK = 0
EXIT_PROBLEM = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # as a shell reports a command Ctrl-C ended


class Interrupted(RoboxError):
    """Ctrl-C, with what it left behind and what the user can do (exit status 130)."""


def fail(message: str, status: int = EXIT_PROBLEM) -> None:
    click.echo(f"robox-cli: error: {message}", err=True)
    sys.exit(status)


class RoboxGroup(click.Group):
    """Turns library errors into one line on stderr and an exit status; never a traceback."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            status = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            where = f" (see '{exc.ctx.command_path} --help')" if exc.ctx else ""
            fail(f"{exc.format_message()}{where}", EXIT_USAGE)
        except click.ClickException as exc:
            fail(exc.format_message(), exc.exit_code)
        except (click.Abort, KeyboardInterrupt):
            fail("interrupted", EXIT_INTERRUPTED)
        except BrokenPipeError:
            from robox.launch import quiet_exit_after_broken_pipe

            quiet_exit_after_broken_pipe()
        sys.exit(status if isinstance(status, int) else EXIT_OK)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except UsageError as exc:
            fail(str(exc), EXIT_USAGE)
        except Interrupted as exc:
            fail(str(exc), EXIT_INTERRUPTED)
        except RoboxError as exc:
            fail(str(exc))
        except BrokenPipeError:  # (here: click's own handling would exit 1)
            from robox.launch import quiet_exit_after_broken_pipe

            quiet_exit_after_broken_pipe()
        except OSError as exc:
            where = f"{exc.filename}: " if exc.filename else ""
            fail(f"{where}{exc.strerror or exc}")


json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")


def emit_json(data: object, err: bool = False) -> None:
    click.echo(json.dumps(data, indent=2), err=err)


def report(output: str, data: object, as_json: bool, text: str) -> None:
    """A command's report on what it wrote to `output`: `data` as JSON or `text`, on
    stderr when the output itself went to standard output (`-o -`)."""
    from robox.fileio import is_stdout

    if as_json:
        emit_json(data, err=is_stdout(output))
    else:
        click.echo(text, err=is_stdout(output))


def number_pair(ctx, param, value: str | None) -> list[float] | None:
    """A click callback: 'A,B' as two numbers."""
    if value is None:
        return None
    parts = value.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return [float(parts[0]), float(parts[1])]
    except ValueError:
        raise click.BadParameter(f"{value!r}: two numbers with a comma between") from None


def at_terminal() -> bool:
    return sys.stdin.isatty()


yes_option = click.option("-y", "--yes", is_flag=True,
                          help="Do it without asking (needed when not at a terminal).")


def confirm(yes: bool, question: str) -> None:
    """Ask before something that destroys data, unless `yes`; away from a terminal,
    refuse rather than wait for an answer nobody can give."""
    if yes:
        return
    if not at_terminal():
        raise UsageError(f"{question.split('?')[0].rstrip()}? Not at a terminal: add --yes "
                         "to confirm")
    if not click.confirm(question + "?", default=False, err=True):
        raise RoboxError("not confirmed: nothing was changed")


def guard_output(output: str, inputs: tuple[str, ...] = (), writing: str = "",
                 yes: bool = False) -> None:
    """Before anything is written to `output`: refuse it when it is one of `inputs`
    (through a link too), and ask before writing `writing` over a file that is a card
    image or an EEPROM dump of another kind."""
    from robox.fileio import is_stdout, refuse_overwriting
    from robox.offline.identify import identify

    if is_stdout(output):
        return
    refuse_overwriting(output, *inputs)
    kind = identify(output)
    if kind is not None and kind != writing:
        confirm(yes, f"{output} is {kind}; write {writing or 'the output'} over it")


PROGRESS_EVERY_S = 60.0  # away from a terminal: a progress line a minute


class Ticker:
    """Progress away from a terminal (a log, a pipe): one line on stderr at most every
    `every_s` of wall time (default PROGRESS_EVERY_S), where a terminal shows a bar."""

    def __init__(self, label: str, total: int, unit: str, every_s: float | None = None,
                 enabled: bool = True):
        import time

        self.label, self.total, self.unit = label, total, unit
        self.every_s = PROGRESS_EVERY_S if every_s is None else every_s
        self.enabled = enabled
        self._clock = time.monotonic
        self._last = self._clock()

    def update(self, done: int) -> None:
        if not self.enabled or self._clock() - self._last < self.every_s:
            return
        self._last = self._clock()
        share = f" ({100 * done / self.total:.0f}%)" if self.total else ""
        click.echo(f"{self.label}: {done} of {self.total} {self.unit}{share}", err=True)

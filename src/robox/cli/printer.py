"""robox-cli commands that drive a printer (real, or the virtual one)."""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import asdict
from pathlib import Path

import click

from robox.cli.common import Interrupted, Ticker, confirm, emit_json, json_option, yes_option
from robox.cli.job_options import (
    ejection_option,
    macros_option,
    nozzle_option,
    parse_ejection,
    valve_option,
)
from robox.errors import NotFoundError, RoboxError, UsageError
from robox.formats.card_file import default_id, make_id
from robox.formats.protocol import error_names
from robox.host.client import (
    DEFAULT_TIMEOUT_MS,
    EEPROMS,
    CatchUpPoints,
    FileTooLarge,
    catch_up_lines,
)
from robox.host.devices import NoPrinter, list_printers, open_printer
from robox.host.transport import Disconnected

WHICH = click.Choice(list(EEPROMS))
POLL_S = 0.5


def device(ctx: click.Context):
    options = ctx.obj or {}
    return open_printer(options.get("device"), options.get("timeout", DEFAULT_TIMEOUT_MS / 1000))


@click.command("printers")
@json_option
def printers_cmd(as_json: bool) -> None:
    """List the Robox printers attached over USB and the virtual printers being served."""
    from robox.sim.served import list_served

    usb_problem = None
    try:
        found = [{"kind": "usb", "device": f"usb:{p.unique_id}", **asdict(p)}
                 for p in list_printers()]
    except NoPrinter as exc:
        found, usb_problem = [], str(exc)
    virtual = [{"kind": "sim", "device": f"sim:{v['state']}", **v} for v in list_served()]
    if usb_problem and not virtual:
        raise NoPrinter(usb_problem)
    if usb_problem:
        click.echo(f"robox-cli: USB not searched: {usb_problem}", err=True)
    if as_json:
        emit_json(found + virtual)
        return
    if not found and not usb_problem:
        click.echo("no Robox attached over USB")
    for p in found:
        if p["in_use"]:
            click.echo(f"(bus {p['bus']}, address {p['address']}): {p['in_use']}")
            continue
        click.echo(f"{p['unique_id']}  firmware {p['revision']}  (bus {p['bus']}, "
                   f"address {p['address']})")
    for v in virtual:
        click.echo(f"{v['unique_id'] or '?'}  firmware {v['revision'] or '?'}  "
                   f"({v['device']}: virtual, served on {v['pty']} by PID {v['pid']})")


@click.command("status")
@json_option
@click.pass_context
def status_cmd(ctx, as_json: bool) -> None:
    """Show the printer's status report."""
    with device(ctx) as printer:
        status = printer.status()
        errors = error_names(printer.errors())
    data = {k: v for k, v in asdict(status).items() if k != "raw"}
    data["errors"] = errors
    if as_json:
        emit_json(data)
        return
    click.echo(describe_job(status))
    for name, t in status.temperatures.items():
        click.echo(f"{name}: {t['measured']:.1f} °C, {describe_heater(t)}")
    click.echo("position: " + " ".join(f"{a}{v:.3f}" for a, v in status.position.items())
               + f" T{status.tool}")
    click.echo("EEPROMs: " + ", ".join(f"{k} {v}" for k, v in status.eeproms.items()
                                       if k != "dual_reel_adaptor"))
    click.echo(f"SD card: {'present' if status.sd_card else 'absent'}")
    click.echo(f"errors: {', '.join(errors) or 'none'}")


def job_state(status) -> str | None:
    """What the job is doing, in words (None with no job)."""
    if status.job is None:
        return None
    return "printing" if status.pause == "running" else status.pause


def describe_job(status) -> str:
    if status.job is None:
        return "job: none" + (" (busy)" if status.busy else "")
    return f"job: {status.job} (line {status.line}, {job_state(status)})"


#: A heater's mode digit in the status report: which of its targets it heats to.
HEATER_MODES = {"0": None, "1": "target", "2": "first_layer_target"}


def describe_heater(t: dict) -> str:
    if t["mode"] == "3":
        return "heating to the filament unload temperature"
    which = HEATER_MODES.get(t["mode"])
    if which is None or which not in t:
        return "off"
    label = "first-layer target" if which == "first_layer_target" else "target"
    return f"{label} {t[which]:.1f}"


@click.command("files")
@json_option
@click.pass_context
def files_cmd(ctx, as_json: bool) -> None:
    """List the files on the printer's SD card, oldest first.

    The printer gives ids only: sizes, line counts and the job flag come from what this
    computer uploaded (`?` otherwise). A repeated id is listed per copy; the newest is
    the one a run by id prints."""
    from robox.host import catalogue

    with device(ctx) as printer:
        listed = printer.files()
        known = catalogue.load(printer.unique_id()) if listed else {}
    files = catalogue.describe(listed, known)
    if as_json:
        emit_json(files)
        return
    if not files:
        click.echo("no files")
        return
    width = max(len(f["id"]) for f in files)
    click.echo(f"{'ID':<{width}}  {'BYTES':>9}  {'LINES':>7}  KIND")
    for f in files:
        size = "?" if f["size"] is None else f"{f['size']:,}"
        lines = "?" if f["lines"] is None else f"{f['lines']:,}"
        kind = "?" if f["job"] is None else ("job" if f["job"] else "file")
        note = "  (newest copy)" if f["newest"] and f["copies"] > 1 else \
            ("  (older copy)" if f["copies"] > 1 else "")
        click.echo(f"{f['id']:<{width}}  {size:>9}  {lines:>7}  {kind:<4}{note}".rstrip())
    if any(f["size"] is None for f in files):
        click.echo("(? : not uploaded from this computer; the printer's list gives ids only)")


@click.command("send-job")
@click.argument("file", type=click.Path(dir_okay=False, readable=False))
@click.option("--id", "file_id", help="Job id (at most 16 characters); default: from the "
                                      "file name and content.")
@click.option("--wait", is_flag=True, help="Follow the print to its end.")
@click.option("--resume", is_flag=True, help="Continue an interrupted upload of FILE.")
@click.option("--raw", is_flag=True, help="Send FILE as it is (comments stripped), without "
                                          "translating a slicer's G-code.")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              help="mm; default: from the printer's reel, else 1.75.")
@nozzle_option
@macros_option
@valve_option
@ejection_option
@json_option
@click.pass_context
def send_job_cmd(ctx, file: str, file_id: str | None, wait: bool, resume: bool, raw: bool,
                 filament_diameter: float | None, nozzle: int | None, macros: Path | None,
                 valve: str, ejection: str | None, as_json: bool) -> None:
    """Upload FILE to the SD card and print it (printing starts after the second chunk).

    A slicer's G-code (PrusaSlicer, Slic3r, Cura, OrcaSlicer, ...: a slicer's header, or
    M82/M83/G92 E) is first translated into a Robox job for the printer's head and reel
    (see `roboxise`); any other file goes as it is."""
    if file_id is not None:
        make_id(file_id)  # refuses an empty or non-ASCII id before the printer is opened
    from robox.gcode import job_file
    from robox.gcode.files import inspect

    volumes = parse_ejection(ejection)
    detected = inspect(file)
    quiet = as_json or not sys.stderr.isatty()
    with device(ctx) as printer:
        options = None
        if not raw and (detected.from_slicer or macros is not None):  # (macros expanded)
            options = printer_options(printer, filament_diameter, nozzle, macros, valve,
                                      volumes)
        with job_file(file, options, detected) as job:
            if job.translation is not None and job.translation.passthrough and not as_json:
                click.echo(f"a Robox job: sent as it is, {job.translation.macros} macro "
                           f"line(s) expanded from {macros}", err=True)
            elif job.translation is not None and not as_json:
                t = job.translation
                click.echo(f"translated {t.slicer} G-code ({t.e_mode} E) for a {t.head} head: "
                           f"{t.volume_mm3['E'] + t.volume_mm3['D']:.0f} mm3, "
                           f"{t.valve_cycles} valve openings (--raw sends it as it is)",
                           err=True)
            summary = _upload(printer, file, job, file_id, resume, wait, quiet, as_json)
    if as_json:
        emit_json(summary)
        return
    if summary["already_stored"]:
        state = "it is printing" if summary["printing"] else \
            f"not printing (`robox-cli run-job {summary['id']}` prints it)"
        click.echo(f"{summary['id']} is already on the card (its upload had finished): "
                   f"nothing sent; {state}")
    else:
        click.echo(f"sent {summary['id']}: {summary['bytes']} bytes, {summary['lines']} "
                   "lines")
    if summary["restarted"]:
        click.echo(f"not printing: the printer lost the interrupted print; once the bed is "
                   f"clear, `robox-cli run-job {summary['id']}` prints it from the start")
        return
    if wait:
        if "simulated_print_time_s" in summary:
            click.echo(f"printed in {_minutes(summary['simulated_print_time_s'])} (simulated)")
        elif getattr(printer, "served", None):
            click.echo(f"printed in {_minutes(summary['print_time_s'])} of wall time (the "
                       "virtual printer's clock runs ahead of the wall's)")
        else:
            click.echo(f"printed in {_minutes(summary['print_time_s'])}")
        for reel, used in summary["filament_used_mm"].items():
            click.echo(f"filament used from {reel}: {used / 1000:.2f} m")
        if summary["catch_up_resumes"]:
            click.echo(f"the print caught up with the upload {summary['catch_up_resumes']} "
                       "time(s) and was resumed")
        click.echo(f"errors: {', '.join(summary['errors']) or 'none'}")


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.1f} s"


def _interrupted_upload(printer, file: str, done: int, size: int) -> str:
    import shlex

    said = f"interrupted after {done} of {size} bytes of the upload"
    if getattr(printer, "virtual", None) is not None:
        return (f"{said}; this printer runs in this command only (--device sim-once) and "
                "is switched off with it: the partial upload is lost")
    return (f"{said}; the printer keeps it open, and prints what it holds if the job had "
            f"begun: `robox-cli send-job {shlex.quote(file)} --resume` goes on from where it "
            "stopped, `robox-cli abort` ends the job")


def _interrupted_wait(printer, name: str) -> str:
    if getattr(printer, "virtual", None) is not None:
        return ("interrupted; this printer runs in this command only (--device sim-once) "
                f"and is switched off with it, {name} with it")
    return (f"interrupted: stopped following {name}, which the printer goes on printing "
            "(`robox-cli status` shows it, `robox-cli abort` ends it)")


def _upload(printer, file: str, job, file_id: str | None, resume: bool,
            wait: bool, quiet: bool, as_json: bool = False) -> dict:
    """Send the job file (a chunk at a time) and, with `wait`, follow its print."""
    from robox.host import catalogue

    name = default_id(Path(file).stem, job.sha1) if file_id is None else file_id
    if len(name.encode("ascii", "replace")) > 16:
        raise UsageError(f"job id {name!r} is longer than 16 characters")
    make_id(name)  # refuses an empty or non-ASCII id
    job.refuse_long_lines()  # before the first chunk
    unique = printer.unique_id()
    _refuse_too_large(printer, unique, job.size)
    before = _reels(printer) if wait else {}
    started = time.monotonic()
    sim = getattr(printer, "virtual", None)
    sim_start = sim.firmware.clock.now if sim else None
    with open(job.path, "rb") as source:
        with click.progressbar(length=job.size, label=f"uploading {name}", file=sys.stderr,
                               hidden=quiet) as bar:
            done_bytes = [0]
            ticker = Ticker(f"uploading {name}", job.size, "bytes",
                            enabled=quiet and not as_json)

            def progress(done: int, total: int) -> None:
                if not as_json:  # (with --json neither the bar nor the ticker shows)
                    bar.update(done - done_bytes[0])
                    ticker.update(done)
                done_bytes[0] = done

            try:
                sent = printer.send_file(source, name, resume=resume, progress=progress,
                                         notice=lambda message: click.echo(message, err=True))
            except KeyboardInterrupt:
                raise Interrupted(_interrupted_upload(printer, file, done_bytes[0],
                                                      job.size)) from None
            except Disconnected:
                raise RoboxError(f"the printer was disconnected after {done_bytes[0]} of "
                                 f"{job.size} bytes; run the same command with --resume to "
                                 "continue") from None
            except FileTooLarge as exc:
                with contextlib.suppress(OSError):
                    catalogue.record_largest_file(unique, exc.largest)
                raise RoboxError(f"{exc}: the job is {job.size} bytes and the card holds "
                                 f"files of at most {exc.largest} bytes (a larger job is "
                                 "refused before upload from now on)") from None
        with contextlib.suppress(OSError):
            catalogue.record(unique, name, job.size, job.lines, True, job.sha1)
        summary = {"id": name, "bytes": job.size, "lines": job.lines,
                   "resumed_from_byte": job.size if sent.already_stored else
                   sent.first_chunk * 512, "restarted": sent.restarted,
                   "already_stored": sent.already_stored, "printing": sent.printing}
        wait = wait and sent.printing
        if wait:
            try:
                points = sent.catch_up if sent.catch_up is not None else \
                    catch_up_lines(source)
                _follow(printer, name, job.lines, points, quiet, as_json)
            except KeyboardInterrupt:
                raise Interrupted(_interrupted_wait(printer, name)) from None
    if wait:
        after = _reels(printer)
        summary["print_time_s"] = round(time.monotonic() - started, 1)
        if sim is not None:
            summary["simulated_print_time_s"] = round(sim.firmware.clock.now - sim_start, 1)
        summary["filament_used_mm"] = {reel: round(before[reel] - after[reel], 1)
                                       for reel in before if reel in after}
        summary["errors"] = error_names(printer.errors())
        summary["catch_up_resumes"] = printer.catch_up_resumes
    return summary


def _refuse_too_large(printer, unique: str, size: int) -> None:
    """Refuse, before its first chunk, a job larger than the printer's card can hold:
    known from a virtual printer's card image, or from an earlier upload the printer
    refused as too large (`robox.host.catalogue`)."""
    from robox.host import catalogue

    largest = printer.largest_file
    if largest is None:
        with contextlib.suppress(OSError):
            largest = catalogue.largest_file(unique)
    if largest is not None and size > largest:
        raise RoboxError(f"the job is {size} bytes; the printer's card holds files of at "
                         f"most {largest} bytes ({largest / 2**20:.1f} MiB): nothing sent")


def printer_options(printer, filament_diameter: float | None, nozzle: int | None,
                    macros: Path | None, valve: str = "automaker",
                    ejection: tuple[float, ...] | None = None):
    """Translation options (robox.gcode.Options) from the printer's head and reels, and
    the user's."""
    from robox.formats.heads import DEFAULT_DIAMETER, HEAD_DEFAULT
    from robox.gcode import Options

    eeproms = printer.status().eeproms
    head = HEAD_DEFAULT
    if eeproms.get("head") == "valid":
        head = str(printer.read_eeprom_fields("head")["type_code"]).strip() or HEAD_DEFAULT
    diameters = []
    for reel in ("reel0", "reel1"):
        value = None
        if filament_diameter is None and eeproms.get(reel) == "valid":
            value = printer.read_eeprom_fields(reel)["filament_diameter"]
        diameters.append(float(value) if value else filament_diameter or DEFAULT_DIAMETER)
    return Options(filament_diameter=(diameters[0], diameters[1]), head=head, nozzle=nozzle,
                   macros=macros, valve=valve, ejection=ejection)


def _reels(printer) -> dict:
    status = printer.status()
    remaining = {}
    for reel in ("reel0", "reel1"):
        if status.eeproms[reel] == "valid":
            remaining[reel] = printer.read_eeprom_fields(reel)["remaining_filament"]
    return remaining


class PausedForError(RoboxError):
    """The print being followed was paused by the printer for an error."""


def _follow(printer, name: str, lines: int, whole: CatchUpPoints, quiet: bool,
            as_json: bool = False) -> None:
    """Follow the print to its end. Asking for the error report on every poll keeps the
    printer counting a host as connected, as AutoMaker did (no flush-needed or slip
    pauses that a host handles). The upload's catch-up pauses are resumed; a pause the
    printer made for an error ends the wait (PausedForError: what happened and what the
    user can do); a pause by the user or by the job is said once and waited out, in
    wall time (a person resumes it), except on a printer in this process, which no
    other command can reach."""
    said = False
    ticker = Ticker(f"printing {name}", lines, "lines", enabled=quiet and not as_json)
    with click.progressbar(length=lines, label=f"printing {name}", file=sys.stderr,
                           hidden=quiet) as bar:
        shown = 0
        while True:
            status = printer.progress()
            if status.job != name:
                bar.update(lines - shown)
                return
            bar.update(max(0, status.line - shown))
            shown = max(shown, status.line)
            ticker.update(shown)
            why = printer.paused_for(name, whole, status)
            if why == "catch-up":
                printer.resume_catch_up()
            elif why:
                raise PausedForError(
                    f"{name} is paused at line {status.line} for an error: "
                    f"{', '.join(error_names(why))}; once its cause is dealt with, "
                    "`robox-cli resume` continues it, or `robox-cli abort` ends it")
            elif why == 0:
                if getattr(printer, "virtual", None) is not None:
                    raise PausedForError(
                        f"{name} is paused at line {status.line} by the job; this printer "
                        "runs in this command only (--device sim-once), so nothing can "
                        "resume it")
                if not said:
                    said = True
                    click.echo(f"\n{name} is paused at line {status.line} (by the user or "
                               "the job): waiting for it to be resumed (Ctrl-C stops waiting "
                               "and leaves it paused; `robox-cli resume` then continues "
                               "it)", err=True)
                time.sleep(POLL_S)
                continue
            else:
                printer.errors()
                said = False
            printer.idle(POLL_S)


@click.command("run-job")
@click.argument("file_id", metavar="[ID]", required=False)
@json_option
@click.pass_context
def run_job_cmd(ctx, file_id: str | None, as_json: bool) -> None:
    """Print a job already on the card (no ID: the last job run)."""
    if file_id is not None:
        make_id(file_id)  # refuses an empty or non-ASCII id
    file_id = file_id or ""
    with device(ctx) as printer:
        if file_id and file_id not in printer.files():
            raise NotFoundError(f"no job {file_id!r} on the printer's card")
        printer.run_job(file_id)
        started = printer.status().job
        if started is None:
            raise RoboxError("the printer did not start the job (no last job?)")
    if as_json:
        emit_json({"printing": started})
    else:
        click.echo(f"printing {started}")


#: Pause states of a job that is paused or parking (a "resuming" job is unparking).
PAUSED = {"pausing", "paused", "selfie pause"}


def _pause_or_resume(ctx, as_json: bool, pause: bool) -> None:
    """Pause (or resume) the job unless it already is; say which happened."""
    with device(ctx) as printer:
        before = printer.status()
        if before.job is None:
            raise NotFoundError("no job is printing: nothing to pause" if pause
                                else "no job on the printer: nothing to resume")
        was_paused = before.pause in PAUSED
        if was_paused != pause:
            (printer.pause if pause else printer.resume)()
        after = printer.status()
    if as_json:
        emit_json({"job": after.job, "line": after.line, "state": job_state(after),
                   "was_paused": was_paused})
        return
    job, line = after.job, after.line
    if pause:
        click.echo(f"{job} was already paused, at line {line}" if was_paused
                   else f"paused {job} at line {line}")
    else:
        click.echo(f"resumed {job} at line {line}" if was_paused
                   else f"{job} was not paused: still printing, at line {line}")


@click.command("pause")
@json_option
@click.pass_context
def pause_cmd(ctx, as_json: bool) -> None:
    """Pause the job (the head parks). Exits 1 when no job is printing."""
    _pause_or_resume(ctx, as_json, pause=True)


@click.command("resume")
@json_option
@click.pass_context
def resume_cmd(ctx, as_json: bool) -> None:
    """Resume a paused job. Exits 1 when there is no job."""
    _pause_or_resume(ctx, as_json, pause=False)


@click.command("abort")
@json_option
@click.pass_context
def abort_cmd(ctx, as_json: bool) -> None:
    """Abort the job and switch the heaters off (with no job, the heaters only)."""
    with device(ctx) as printer:
        before = printer.status()
        printer.abort()
    result = {"aborted": before.job, "line": before.line if before.job else None}
    if as_json:
        emit_json(result)
    elif before.job is None:
        click.echo("no job was printing; heaters switched off")
    else:
        click.echo(f"aborted {before.job} at line {before.line}; heaters switched off")


@click.command("reset")
@json_option
@click.pass_context
def reset_cmd(ctx, as_json: bool) -> None:
    """Reset the printer (as switching it off and on, keeping the power)."""
    with device(ctx) as printer:
        printer.reset()
    if as_json:
        emit_json({"reset": True})
    else:
        click.echo("reset")


@click.command("gcode")
@click.argument("lines", nargs=-1, required=True)
@json_option
@click.pass_context
def gcode_cmd(ctx, lines: tuple[str, ...], as_json: bool) -> None:
    """Send G-code lines; prints the response of reporting codes (M105, M114, ...)."""
    for line in lines:
        if not line.isascii():
            raise UsageError(f"{line!r} is not ASCII G-code")
    answers = []
    with device(ctx) as printer:
        for line in lines:
            response = printer.gcode(line + "\r").replace("\r\n", "\n")
            answers.append({"line": line, "response": response})
            if response and not as_json:
                click.echo(response, nl=False)
    if as_json:
        emit_json(answers)


@click.command("errors")
@click.option("--clear", is_flag=True, help="Clear the latched errors.")
@json_option
@click.pass_context
def errors_cmd(ctx, clear: bool, as_json: bool) -> None:
    """Show the printer's latched errors (and clear them with --clear)."""
    with device(ctx) as printer:
        names = error_names(printer.errors())
        if clear:
            printer.clear_errors()
    if as_json:
        emit_json({"errors": names, "cleared": clear})
    else:
        click.echo(", ".join(names) or "no errors" + (" (cleared)" if clear and names else ""))


@click.command("read-eeprom")
@click.argument("which", type=WHICH)
@json_option
@click.pass_context
def read_eeprom_cmd(ctx, which: str, as_json: bool) -> None:
    """Read a head or reel EEPROM and show its fields."""
    with device(ctx) as printer:
        fields = printer.read_eeprom_fields(which, shown=True)
    if as_json:
        emit_json(fields)
    else:
        width = max(len(n) for n in fields)
        for name, value in fields.items():
            click.echo(f"{name:<{width}}  {value}")


@click.command("write-eeprom")
@click.argument("which", type=WHICH)
@click.argument("assignments", nargs=-1, required=True, metavar="FIELD=VALUE...")
@json_option
@click.pass_context
def write_eeprom_cmd(ctx, which: str, assignments: tuple[str, ...], as_json: bool) -> None:
    """Change fields of a head or reel EEPROM."""
    from robox.formats import eeprom as fmt
    from robox.offline.eeprom import parse_assignments

    pairs = dict(parse_assignments(list(assignments)))
    kind = "head" if which == "head" else "reel"
    for name, value in pairs.items():
        try:
            fmt.field(kind, name).encode(value)
        except NotFoundError as exc:
            raise UsageError(str(exc)) from None
    with device(ctx) as printer:
        printer.write_eeprom_fields(which, pairs)
    if as_json:
        emit_json({"eeprom": which, "set": pairs})
    else:
        click.echo(f"{which}: set {', '.join(pairs)}")


@click.command("format-eeprom")
@click.argument("which", type=WHICH)
@yes_option
@json_option
@click.pass_context
def format_eeprom_cmd(ctx, which: str, yes: bool, as_json: bool) -> None:
    """Format (zero) a head or reel EEPROM: its calibration or filament data is lost."""
    confirm(yes, f"Format the {which} EEPROM? Everything it holds is lost")
    with device(ctx) as printer:
        printer.format_eeprom(which)
    if as_json:
        emit_json({"eeprom": which, "formatted": True})
    else:
        click.echo(f"{which}: formatted")


@click.command("update-firmware")
@click.argument("bin_file", metavar="BIN", type=click.Path(dir_okay=False, readable=False))
@json_option
@click.pass_context
def update_firmware_cmd(ctx, bin_file: str, as_json: bool) -> None:
    """Verify BIN, upload it, flash it, and check the printer comes back."""
    from robox.formats.firmware import image_revision
    from robox.offline.firmware import read_input

    image = read_input(bin_file)
    with device(ctx) as printer:
        before = printer.revision()
        with click.progressbar(length=2 * len(image), label="uploading firmware",
                               file=sys.stderr, hidden=not sys.stderr.isatty()) as bar:
            after_printer = printer.update_firmware(
                image, progress=lambda done, total: bar.update(done - bar.pos))
        after = after_printer.revision()
    declared = image_revision(image)
    if declared is not None and after != declared[:8]:  # (0xb4 holds 8 characters)
        raise RoboxError(f"the printer came back with firmware {after}, but the image is "
                         f"{declared}: the update did not take")
    if as_json:
        emit_json({"before": before, "after": after})
    else:
        click.echo(f"firmware {before} -> {after}")


COMMANDS = [printers_cmd, status_cmd, files_cmd, send_job_cmd, run_job_cmd, pause_cmd,
            resume_cmd, abort_cmd, gcode_cmd, errors_cmd, read_eeprom_cmd, write_eeprom_cmd,
            format_eeprom_cmd, update_firmware_cmd, reset_cmd]

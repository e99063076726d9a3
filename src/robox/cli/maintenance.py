"""robox-cli purge, level-gantry, load, unload, head-change, eject-stuck and calibrate:
AutoMaker's looking-after jobs as guided sequences (robox.maintenance, robox.calibration)."""

from __future__ import annotations

import contextlib
from dataclasses import asdict

import click

from robox.cli.common import at_terminal, emit_json, json_option, number_pair

yes_answer = click.option("-y", "--yes", "answer_yes", is_flag=True, default=None,
                          help="Answer the question yes (needed away from a terminal).")
feed_option = click.option("--feed", type=click.Choice(["E", "D"]), default="E",
                           show_default=True,
                           help="Which feed: E (reel 0), or D (reel 1, a dual-material head).")
dry_run_option = click.option("--dry-run", is_flag=True,
                              help="Show the steps; send nothing that moves or heats.")


def _ask(key: str, text: str) -> bool:
    return click.confirm(text, default=False, err=True)


def _choose(key: str, text: str, choices: tuple[str, ...]) -> str:
    return click.prompt(text, type=click.Choice(choices, case_sensitive=False), err=True)


def _run(ctx, make, answers: dict, dry_run: bool, as_json: bool, read_printer=None):
    """Open the printer, build the sequence (`make(printer, ...)`) and run it; the
    report as lines or JSON."""
    from robox.cli.printer import device

    say = (lambda _text: None) if as_json else (lambda text: click.echo(text, err=False))
    ask = _ask if at_terminal() else None
    with device(ctx) if (read_printer or not dry_run) else contextlib.nullcontext() as printer:
        facts = read_printer(printer) if read_printer else {}
        sequence = make(printer, answers, ask, say, dry_run, **facts)
        sequence.choose = _choose if ask is not None else None
        report = sequence.run()
    if as_json:
        emit_json(asdict(report))
        return
    for name, value in report.measured.items():
        click.echo(f"measured {name}: {value}")
    for name, value in report.written.items():
        click.echo(f"wrote {name}: {value}")
    click.echo(f"{report.sequence}: {'dry run, nothing sent' if dry_run else 'done'}")


def _head(printer) -> dict:
    status = printer.status()
    head = printer.read_eeprom_fields("head") if status.eeproms["head"] == "valid" else {}
    return {"head": head}


def _head_and_reels(printer) -> dict:
    status = printer.status()
    if status.job:
        from robox.errors import RoboxError

        raise RoboxError(f"a job is running ({status.job}): abort it or let it finish first")
    head = printer.read_eeprom_fields("head") if status.eeproms["head"] == "valid" else {}
    reels = {which: printer.read_eeprom_fields(which)
             for which in ("reel0", "reel1") if status.eeproms[which] == "valid"}
    return {"head": head, "reels": reels}


@click.command("purge")
@click.option("--nozzle", type=click.IntRange(0, 1),
              help="Purge this nozzle only (default: every nozzle the head has).")
@click.option("--temperature", type=click.FloatRange(150, 500), metavar="C",
              help="Purge at this temperature (default: AutoMaker's, halfway from the "
                   "material the head last melted to the reel's).")
@yes_answer
@dry_run_option
@json_option
@click.pass_context
def purge_cmd(ctx, nozzle, temperature, answer_yes, dry_run, as_json) -> None:
    """Purge the old material out of the nozzle(s) after a material change.

    Home, level, heat, pressurise and lay purge lines at the front of the bed, then
    record the new material in the head."""
    from robox.maintenance import Purge

    def make(printer, answers, ask, say, dry_run, head, reels):
        return Purge(printer, answers, ask, say, dry_run, nozzle=nozzle,
                     temperature=temperature, head=head, reels=reels)

    _run(ctx, make, {"yes": answer_yes}, dry_run, as_json, read_printer=_head_and_reels)


@click.command("level-gantry")
@yes_answer
@dry_run_option
@json_option
@click.pass_context
def level_gantry_cmd(ctx, answer_yes, dry_run, as_json) -> None:
    """Level the gantry from the Z switch at each leadscrew.

    Z is homed at each leadscrew, the gantry levelled (G38) and Z homed in the middle;
    prints the Z difference the printer measured."""
    from robox.maintenance import LevelGantry

    def make(printer, answers, ask, say, dry_run):
        return LevelGantry(printer, answers, ask, say, dry_run)

    _run(ctx, make, {"yes": answer_yes}, dry_run, as_json)


@click.command("unload")
@feed_option
@yes_answer
@dry_run_option
@json_option
@click.pass_context
def unload_cmd(ctx, feed, answer_yes, dry_run, as_json) -> None:
    """Unload a feed's filament: the printer heats, moves right and pulls it back."""
    from robox.maintenance import Unload

    def make(printer, answers, ask, say, dry_run, head):
        return Unload(printer, answers, ask, say, dry_run, feed=feed, head=head)

    _run(ctx, make, {"yes": answer_yes}, dry_run, as_json, read_printer=_head)


@click.command("head-change")
@yes_answer
@click.option("--swapped", "answer_swapped", is_flag=True, default=None,
              help="Answer that the new head is in place (away from a terminal).")
@dry_run_option
@json_option
@click.pass_context
def head_change_cmd(ctx, answer_yes, answer_swapped, dry_run, as_json) -> None:
    """Change the head: unload, park at the front and unlock, then read the new one.

    As AutoMaker's Remove head: home, shut the valve, park at the front, unload the
    filament and unlock the door; then, once the new head is in place, read its EEPROM."""
    from robox.maintenance import HeadChange

    def make(printer, answers, ask, say, dry_run, head):
        return HeadChange(printer, answers, ask, say, dry_run, head=head)

    _run(ctx, make, {"yes": answer_yes, "swapped": answer_swapped}, dry_run, as_json,
         read_printer=_head)


@click.command("eject-stuck")
@click.option("--nozzle", type=click.IntRange(0, 1),
              help="A dual-material head: free this nozzle only (default: both).")
@yes_answer
@dry_run_option
@json_option
@click.pass_context
def eject_stuck_cmd(ctx, nozzle, answer_yes, dry_run, as_json) -> None:
    """Free filament stuck in the head: heat, push through, cool and pull it out.

    As AutoMaker's Eject stuck material: the reel's first-layer temperature, a short push
    through each nozzle, then a neck drawn at 140 C (a dual-material head: 160 C),
    snapped at 125 C and pulled out. A dual-material head's nozzles are freed in turn."""
    from robox.maintenance import EjectStuck

    def make(printer, answers, ask, say, dry_run, head, reels):
        return EjectStuck(printer, answers, ask, say, dry_run, head=head, reels=reels,
                          nozzle=nozzle)

    _run(ctx, make, {"yes": answer_yes}, dry_run, as_json, read_printer=_head_and_reels)


@click.command("load")
@feed_option
@click.option("--inserted", "answer_inserted", is_flag=True, default=None,
              help="Answer that the drive has taken the filament (away from a terminal).")
@dry_run_option
@json_option
@click.pass_context
def load_cmd(ctx, feed, answer_inserted, dry_run, as_json) -> None:
    """Load a feed: push the filament in until the drive takes it; the printer does the rest."""
    from robox.maintenance import Load

    def make(printer, answers, ask, say, dry_run, head):
        return Load(printer, answers, ask, say, dry_run, feed=feed, head=head)

    _run(ctx, make, {"inserted": answer_inserted}, dry_run, as_json, read_printer=_head)


@click.group("calibrate")
def calibrate() -> None:
    """Calibrate the head: nozzle heights, needle openings, X/Y alignment.

    Each is a guided sequence that writes what it measured to the head's EEPROM; Ctrl-C
    or an error puts the head's data back and switches the heaters off."""


def _calibrate(ctx, kind, answers: dict, dry_run: bool, as_json: bool) -> None:
    def make(printer, answers, ask, say, dry_run, head, reels):
        return kind(printer, answers, ask, say, dry_run, head=head, reels=reels)

    _run(ctx, make, answers, dry_run, as_json, read_printer=_head_and_reels)


@calibrate.command("nozzle-height")
@yes_answer
@click.option("--paper-z", type=click.FloatRange(0.0, 2.0), metavar="MM",
              help="Answer the paper question: the Z at which a sheet of paper just drags "
                   "under nozzle 0 (away from a terminal).")
@dry_run_option
@json_option
@click.pass_context
def nozzle_height_cmd(ctx, answer_yes, paper_z, dry_run, as_json) -> None:
    """The nozzles' Z offsets: their Z difference probed on the bed, nozzle 0's height
    judged with a sheet of paper.

    As AutoMaker's nozzle height calibration: offsets cleared, the head heated and the
    gantry levelled, the bed probed eleven times with the nozzles in turn (G28 Z?,
    M113), then nozzle 0 raised 0.05 mm at a time until the paper drags."""
    from robox.calibration import NozzleHeight

    _calibrate(ctx, NozzleHeight, {"yes": answer_yes, "paper_z": paper_z}, dry_run, as_json)


@calibrate.command("nozzle-opening")
@yes_answer
@click.option("--opens-at", callback=number_pair, metavar="B0,B1",
              help="Answer the opening questions: the B shown when plastic first came out "
                   "of nozzle 0 and of nozzle 1 (negative), away from a terminal.")
@dry_run_option
@json_option
@click.pass_context
def nozzle_opening_cmd(ctx, answer_yes, opens_at, dry_run, as_json) -> None:
    """The needles' B offsets: where each nozzle's needle opens, watched with filament in.

    Needs filament at the nozzle. Each feed is pressurised against its shut needle and
    the valve opened 0.02 B at a time; the last B it stayed shut at is written."""
    from robox.calibration import NozzleOpening

    if opens_at is not None and not opens_at[0] > 0.0 > opens_at[1]:
        raise click.BadParameter("nozzle 0's B is positive, nozzle 1's negative",
                                 param_hint="--opens-at")
    _calibrate(ctx, NozzleOpening, {"yes": answer_yes, "opens_at": opens_at}, dry_run,
               as_json)


@calibrate.command("xy")
@yes_answer
@click.option("--x-pair", type=click.Choice(list("ABCDEFGHIJK"), case_sensitive=False),
              help="Answer which pair of the lines across X lines up (A to K).")
@click.option("--y-pair", type=click.Choice([str(k) for k in range(1, 12)]),
              help="Answer which pair of the lines along Y lines up (1 to 11).")
@dry_run_option
@json_option
@click.pass_context
def xy_cmd(ctx, answer_yes, x_pair, y_pair, dry_run, as_json) -> None:
    """The nozzles' X and Y alignment, from a printed pattern of lines.

    As AutoMaker's: a pattern of eleven pairs of lines across X and along Y, nozzle 1's
    shifted 0.05 mm more in each; the pair that lines up sets the offsets."""
    from robox.calibration import XYAlignment

    _calibrate(ctx, XYAlignment, {"yes": answer_yes, "x_pair": x_pair and x_pair.upper(),
                                  "y_pair": y_pair}, dry_run, as_json)

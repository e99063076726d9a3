"""robox-cli purge and level-gantry: AutoMaker's looking-after jobs as guided sequences
(src/robox/maintenance.py)."""

from __future__ import annotations

import contextlib
from dataclasses import asdict

import click

from robox.cli.common import at_terminal, emit_json, json_option

yes_answer = click.option("-y", "--yes", "answer_yes", is_flag=True, default=None,
                          help="Answer the question yes (needed away from a terminal).")
feed_option = click.option("--feed", type=click.Choice(["E", "D"]), default="E",
                           show_default=True,
                           help="Which feed: E (reel 0), or D (reel 1, a dual-material head).")
dry_run_option = click.option("--dry-run", is_flag=True,
                              help="Show the steps; send nothing that moves or heats.")


def _ask(key: str, text: str) -> bool:
    return click.confirm(text, default=False, err=True)


def _run(ctx, make, answers: dict, dry_run: bool, as_json: bool, read_printer=None):
    """Open the printer, build the sequence (`make(printer, ...)`) and run it; the
    report as lines or JSON."""
    from robox.cli.printer import device

    say = (lambda _text: None) if as_json else (lambda text: click.echo(text, err=False))
    ask = _ask if at_terminal() else None
    with device(ctx) if (read_printer or not dry_run) else contextlib.nullcontext() as printer:
        facts = read_printer(printer) if read_printer else {}
        sequence = make(printer, answers, ask, say, dry_run, **facts)
        report = sequence.run()
    if as_json:
        emit_json(asdict(report))
        return
    for name, value in report.measured.items():
        click.echo(f"measured {name}: {value}")
    for name, value in report.written.items():
        click.echo(f"wrote {name}: {value}")
    click.echo(f"{report.sequence}: {'dry run, nothing sent' if dry_run else 'done'}")


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

    def make(printer, answers, ask, say, dry_run):
        return Unload(printer, answers, ask, say, dry_run, feed=feed)

    _run(ctx, make, {"yes": answer_yes}, dry_run, as_json)


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

    def read_head(printer) -> dict:
        status = printer.status()
        head = printer.read_eeprom_fields("head") if status.eeproms["head"] == "valid" else {}
        return {"head": head}

    def make(printer, answers, ask, say, dry_run, head):
        return HeadChange(printer, answers, ask, say, dry_run, head=head)

    _run(ctx, make, {"yes": answer_yes, "swapped": answer_swapped}, dry_run, as_json,
         read_printer=read_head)


@click.command("eject-stuck")
@yes_answer
@dry_run_option
@json_option
@click.pass_context
def eject_stuck_cmd(ctx, answer_yes, dry_run, as_json) -> None:
    """Free filament stuck in the head: heat, push through, cool and pull it out.

    As AutoMaker's Eject stuck material: the reel's first-layer temperature, a short push
    through each nozzle, then a neck drawn at 140 C, snapped at 125 C and pulled out."""
    from robox.maintenance import EjectStuck

    def make(printer, answers, ask, say, dry_run, head, reels):
        return EjectStuck(printer, answers, ask, say, dry_run, head=head, reels=reels)

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

    def make(printer, answers, ask, say, dry_run):
        return Load(printer, answers, ask, say, dry_run, feed=feed)

    _run(ctx, make, {"inserted": answer_inserted}, dry_run, as_json)

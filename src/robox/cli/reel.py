"""robox-cli reel: program a filament reel's EEPROM for any filament, and read one back
in the same terms (src/robox/reels.py)."""

from __future__ import annotations

from pathlib import Path

import click

from robox.cli.common import confirm, emit_json, json_option, yes_option
from robox.errors import RoboxError, UsageError
from robox.formats import eeprom as fmt
from robox.reels import MATERIALS, Definition, material, with_overrides

REEL = click.option("--reel", "reel", type=click.Choice(["0", "1"]), default="0",
                    show_default=True,
                    help="Which reel: 0, or 1 (behind a dual-reel adaptor).")

LABELS = (
    ("id", "filament ID", ""), ("name", "name", ""), ("material_type", "material", ""),
    ("colour", "colour", ""), ("nozzle_c", "nozzle", " °C"),
    ("first_layer_nozzle_c", "nozzle, first layer", " °C"), ("bed_c", "bed", " °C"),
    ("first_layer_bed_c", "bed, first layer", " °C"), ("ambient_c", "ambient", " °C"),
    ("diameter_mm", "diameter", " mm"), ("filament_multiplier", "filament multiplier", ""),
    ("feed_rate_multiplier", "feed rate multiplier", ""), ("remaining_m", "remaining", " m"),
)


def show_lines(shown: dict) -> list[str]:
    width = max(len(label) for _, label, _ in LABELS)
    out = []
    for key, label, unit in LABELS:
        value = shown.get(key)
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        text = "(kept as it is)" if value is None else f"{value}{unit}"
        out.append(f"{label:<{width}}  {text}")
    return out


@click.group("reel")
def reel() -> None:
    """Filament reels: program a reel's EEPROM for any filament, and read one back."""


@reel.command("materials")
@json_option
def materials_cmd(as_json: bool) -> None:
    """List the catalogue of materials `reel program` knows."""
    if as_json:
        emit_json({name: d.shown() for name, d in MATERIALS.items()})
        return
    for name, d in MATERIALS.items():
        click.echo(f"{name:<6} {d.name:<26} nozzle {d.nozzle_c:g}/{d.first_layer_nozzle_c:g} °C"
                   f"  bed {d.bed_c:g}/{d.first_layer_bed_c:g} °C  ambient {d.ambient_c:g} °C")


def _definition(material_name: str | None, from_file: str | None, **overrides) -> Definition:
    if (material_name is None) == (from_file is None):
        raise UsageError("name a MATERIAL from the catalogue, or give --from FILE "
                         "(robox-cli reel materials lists the catalogue)")
    base = material(material_name) if material_name else Definition.from_file(Path(from_file))
    return with_overrides(base, **overrides)


@reel.command("program")
@click.argument("material_name", metavar="[MATERIAL]", required=False)
@click.option("--from", "from_file", metavar="FILE",
              help="A reel definition file (TOML, or JSON by its .json suffix).")
@REEL
@click.option("--name", help="The name the reel shows (up to 40 characters).")
@click.option("--id", "filament_id", help="The filament ID (up to 16 characters).")
@click.option("--colour", help="The display colour, RRGGBB.")
@click.option("--diameter", "diameter_mm", type=float, help="Filament diameter, mm.")
@click.option("--remaining", "remaining_m", type=float, metavar="METRES",
              help="Filament on the reel, metres (default: leave the reel's own).")
@click.option("--format", "format_blank", is_flag=True,
              help="Format the reel's EEPROM first if it holds no valid data (a new chip).")
@click.option("--dry-run", is_flag=True, help="Show what would be written; touch nothing.")
@yes_option
@json_option
@click.pass_context
def program_cmd(ctx, material_name, from_file, reel, name, filament_id, colour, diameter_mm,
                remaining_m, format_blank, dry_run, yes, as_json) -> None:
    """Write a reel's EEPROM for a filament: a MATERIAL from the catalogue (PLA, PETG,
    ABS, ASA, TPU, NYLON, PVA, HIPS, PC) or a definition file, with any values given
    as options in their place. Values the printer would clamp are refused before
    anything is written, and the whole EEPROM is written in one command, then read
    back."""
    from robox.cli.printer import device

    definition = _definition(material_name, from_file, name=name, id=filament_id,
                             colour=colour, diameter_mm=diameter_mm,
                             remaining_m=remaining_m)
    which = f"reel{reel}"
    if dry_run:
        _report(which, definition.shown(), as_json, "would write", dry_run=True)
        return
    with device(ctx) as printer:
        status = printer.status()
        head_state = status.eeproms["head"]
        head_type = ""
        if head_state == "valid":
            head_type = printer.read_eeprom_fields("head")["type_code"]
        definition.check_for_head(head_type)
        state = status.eeproms[which]
        if state == "not present":
            raise RoboxError(f"{which}: no reel EEPROM is there (is the reel in place?)")
        if state != "valid":
            if not format_blank:
                raise UsageError(f"{which}: the reel's EEPROM holds no valid data; add "
                                 "--format to format it first (a new chip)")
            confirm(yes, f"Format the {which} EEPROM and program it")
            printer.format_eeprom(which)
        before = printer.read_eeprom(which)
        data = definition.apply(before)
        if data != before:
            printer.write_eeprom(which, 0, data)
        after = printer.read_eeprom(which)
        if after != fmt.mask7(data):
            raise RoboxError(f"{which}: the EEPROM reads back other than was written")
    shown = Definition.from_fields(fmt.shown_fields("reel", after)).shown()
    _report(which, shown, as_json, "wrote" if data != before else "already held")


def _report(which: str, shown: dict, as_json: bool, verb: str, dry_run: bool = False) -> None:
    if as_json:
        emit_json({"reel": which, "dry_run": dry_run, "written": not dry_run,
                   "definition": shown})
        return
    click.echo(f"{which}: {verb}:")
    for line in show_lines(shown):
        click.echo("  " + line)


@reel.command("show")
@REEL
@json_option
@click.pass_context
def show_cmd(ctx, reel, as_json) -> None:
    """Read a reel's EEPROM and show it in the terms `reel program` takes (its JSON is
    a definition file)."""
    from robox.cli.printer import device

    which = f"reel{reel}"
    with device(ctx) as printer:
        state = printer.status().eeproms[which]
        if state == "not present":
            raise RoboxError(f"{which}: no reel EEPROM is there (is the reel in place?)")
        if state != "valid":
            raise RoboxError(f"{which}: the reel's EEPROM holds no valid data "
                             "(reel program --format writes one)")
        values = printer.read_eeprom_fields(which)
    shown = Definition.from_fields(values).shown()
    if as_json:
        emit_json(shown)
        return
    known = [n for n, d in MATERIALS.items() if d.id == shown["id"]]
    click.echo(f"{which}:" + (f" catalogue material {known[0]}" if known else ""))
    for line in show_lines(shown):
        click.echo("  " + line)

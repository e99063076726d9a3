"""robox-cli eeprom: head and reel EEPROM dumps (512-byte chip images)."""

from __future__ import annotations

import sys

import click

from robox.cli.common import (
    EXIT_PROBLEM,
    emit_json,
    guard_output,
    json_option,
    report,
    yes_option,
)
from robox.fileio import write_atomically
from robox.offline import eeprom as dumps

set_option = click.option("--set", "assignments", multiple=True, metavar="FIELD=VALUE",
                          help="Set a field (repeatable), e.g. --set filament_diameter=1.75")
KINDS = click.Choice(["reel", "head"])


@click.group()
def eeprom() -> None:
    """Build, inspect and change head and reel EEPROM dumps."""


@eeprom.command("new")
@click.argument("kind", type=KINDS)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, readable=False),
              help="The dump file to write (- for standard output).")
@set_option
@yes_option
@json_option
def new_cmd(kind: str, output: str, assignments: tuple[str, ...], yes: bool,
            as_json: bool) -> None:
    """Write a KIND EEPROM dump with both banks valid (a reel's multipliers 1.0, every
    other field zero, unless --set)."""
    dump = dumps.new_dump(kind, list(assignments))  # (the fields checked first)
    guard_output(output, (), "an EEPROM dump", yes)
    write_atomically(output, dump)
    report(output, {"dump": output, "kind": kind, "set": list(assignments)}, as_json,
           f"{output}: new {kind} EEPROM, both banks valid")


@eeprom.command("show")
@click.argument("dump", type=click.Path(dir_okay=False, readable=False))
@click.option("--kind", type=KINDS, help="Field map to use (default: guessed from the type "
                                         "code, which only heads have).")
@json_option
def show_cmd(dump: str, kind: str | None, as_json: bool) -> None:
    """Show both banks, the copy a printer would load, and its fields."""
    report = dumps.show_dump(dump, kind)
    if as_json:
        emit_json(report)
        return
    for bank in report["banks"]:
        state = "good" if bank["crc_good"] else "BAD"
        click.echo(f"bank {bank['bank']} at {bank['address']:#05x}: CRC {state} "
                   f"(stored {bank['crc_stored']}, computed {bank['crc_computed']})")
    if report["loaded_bank"] is None:
        click.echo("a printer would load: nothing (present but not valid)")
        return
    click.echo(f"a printer would load: bank {report['loaded_bank']} as a {report['kind']} "
               "EEPROM" + ("" if report["banks_identical"] else " (the banks differ)"))
    width = max(len(name) for name in report["fields"])
    for name, value in report["fields"].items():
        click.echo(f"  {name:<{width}}  {value['value']}")


@eeprom.command("set")
@click.argument("dump", type=click.Path(dir_okay=False, readable=False))
@click.argument("assignments", nargs=-1, required=True, metavar="FIELD=VALUE...")
@click.option("--kind", type=KINDS, help="Field map to use (default: guessed).")
@json_option
def set_cmd(dump: str, assignments: tuple[str, ...], kind: str | None, as_json: bool) -> None:
    """Change fields the way the printer does, leaving both banks valid."""
    result = dumps.set_dump(dump, list(assignments), kind)
    if as_json:
        emit_json(result)
        return
    click.echo(f"{dump}: set {', '.join(result['changed'])} ({result['kind']} EEPROM, "
               f"{result['writes']} bytes rewritten)")


@eeprom.command("fsck")
@click.argument("dump", type=click.Path(dir_okay=False, readable=False))
@json_option
def fsck_cmd(dump: str, as_json: bool) -> None:
    """Exit 0 if a printer would load DUMP as valid, 1 otherwise, saying why."""
    report = dumps.fsck_dump(dump)
    if as_json:
        emit_json(report)
    else:
        verdict = "valid" if report["valid"] else "NOT valid"
        click.echo(f"{dump}: {verdict}: {report['reason']}")
    if not report["valid"]:
        sys.exit(EXIT_PROBLEM)

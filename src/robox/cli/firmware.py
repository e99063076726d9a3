"""robox-cli firmware: anti-checksums, verification and SD firmware files."""

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
from robox.formats.firmware import DEFAULT_OFFSET
from robox.offline import firmware as images

offset_option = click.option("--offset", "offset_text", default=f"{DEFAULT_OFFSET:#x}",
                             show_default=True, help="Where the anti-checksum word lives (hex).")


@click.group()
def firmware() -> None:
    """Firmware images: insert and verify anti-checksums, convert for the SD card."""


@firmware.command("inject")
@click.argument("bin_file", metavar="BIN", type=click.Path(dir_okay=False, readable=False))
@offset_option
@json_option
def inject_cmd(bin_file: str, offset_text: str, as_json: bool) -> None:
    """Insert the anti-checksum into BIN in place, after every check has passed."""
    result = images.inject(bin_file, images.parse_offset(offset_text))
    if as_json:
        emit_json(result)
    else:
        click.echo(f"{bin_file}: anti-checksum 0x{result['anti_checksum']} inserted at "
                   f"{result['offset']:#x}")


@firmware.command("verify")
@click.argument("file", type=click.Path(dir_okay=False, readable=False))
@offset_option
@json_option
def verify_cmd(file: str, offset_text: str, as_json: bool) -> None:
    """Check FILE (.bin or SD firmware text) as a printer would. Exit 0 only if accepted."""
    report = images.verify(file, images.parse_offset(offset_text))
    if as_json:
        emit_json(report)
    else:
        size = "?" if report["size"] is None else f"{report['size']} bytes"
        click.echo(f"{file}: {report['kind']}, {size}, {report['characters']} characters as "
                   "SD text")
        click.echo(f"  page aligned: {'yes' if report['page_aligned'] else 'no'}; word sum: "
                   f"{report['checksum'] or '?'}; word at {report['offset']:#x}: "
                   f"{report['word_at_offset'] or 'outside the image'}")
        if report["overlaps_parameter_pages"]:
            click.echo("  note: the image reaches into the parameter pages (507, 508)")
        for failure in report["failures"]:
            click.echo(f"  refused: {failure['message']} ({failure['detail']})")
        click.echo("  a printer would accept it" if report["accepted"]
                   else "  a printer would refuse it")
    if not report["accepted"]:
        sys.exit(EXIT_PROBLEM)


@firmware.command("to-sd")
@click.argument("bin_file", metavar="BIN", type=click.Path(dir_okay=False, readable=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, readable=False),
              help="The file to write (- for standard output).")
@yes_option
@json_option
def to_sd_cmd(bin_file: str, output: str, yes: bool, as_json: bool) -> None:
    """Write BIN as an SD firmware file (two upper-case hex digits per byte)."""
    guard_output(output, (bin_file,), "an SD firmware file", yes)
    result = images.to_sd(bin_file, output)
    report(output, result, as_json,
           f"{output}: {result['characters']} characters from {result['bytes']} bytes")


@firmware.command("from-sd")
@click.argument("file", type=click.Path(dir_okay=False, readable=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, readable=False),
              help="The file to write (- for standard output).")
@yes_option
@json_option
def from_sd_cmd(file: str, output: str, yes: bool, as_json: bool) -> None:
    """Write the binary held in an SD firmware file."""
    guard_output(output, (file,), "a firmware image", yes)
    result = images.from_sd(file, output)
    report(output, result, as_json,
           f"{output}: {result['bytes']} bytes from {result['characters']} characters")

"""robox-cli sdcard: card images in the printer's own format."""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import click

from robox.cli.common import (
    EXIT_PROBLEM,
    confirm,
    emit_json,
    guard_output,
    json_option,
    yes_option,
)
from robox.cli.job_options import (
    ejection_option,
    macros_option,
    nozzle_option,
    parse_ejection,
    valve_option,
)
from robox.errors import ImageError
from robox.fileio import open_input, write_atomically
from robox.formats.heads import DEFAULT_DIAMETER, HEAD_DEFAULT
from robox.formats.sdcard import default_id
from robox.offline import sdcard as images


@click.group()
def sdcard() -> None:
    """Build and inspect SD card images (the printer's circular file system)."""


@sdcard.command("format")
@click.argument("image", type=click.Path(dir_okay=False, readable=False))
@click.option("--size", help="Card size: 8MiB, 512KiB, 1GiB or a block count such as 16384b. "
                             "Required to create an image.")
@yes_option
@json_option
def format_cmd(image: str, size: str | None, yes: bool, as_json: bool) -> None:
    """Create IMAGE as a freshly formatted card, or reformat an existing card image
    (its files are lost: asks first, unless --yes)."""
    blocks = images.parse_size(size) if size is not None else None
    result = images.format_image(
        image, blocks, lambda: confirm(yes, f"Reformat {image}? Every file on it is lost"))
    if as_json:
        emit_json(result)
    else:
        verb = "created" if result["created"] else "reformatted"
        click.echo(f"{image}: {verb}, {result['capacity_blocks']} blocks "
                   f"({result['capacity_blocks'] // 2} KiB)")


@sdcard.command("ls")
@click.argument("image", type=click.Path(dir_okay=False, readable=False))
@json_option
def ls_cmd(image: str, as_json: bool) -> None:
    """List the committed files of IMAGE, oldest first."""
    result = images.list_image(image)
    if as_json:
        emit_json(result)
        return
    if result["mount"] == "recover":
        click.echo(f"{image}: block 0 is damaged; listing its recovery copy", err=True)
    click.echo(f"{'slot':>4}  {'id':<16}  {'job':<3}  {'start':>8}  {'length':>10}")
    for entry in result["files"]:
        mark = "  last job" if entry["last_job"] else ""
        click.echo(f"{entry['slot']:>4}  {entry['id']:<16}  {'yes' if entry['job'] else 'no':<3}"
                   f"  {entry['start_block']:>8}  {entry['length']:>10}{mark}")
    click.echo(f"{len(result['files'])} file(s), card of {result['capacity_blocks']} blocks")


@sdcard.command("put")
@click.argument("image", type=click.Path(dir_okay=False, readable=False))
@click.argument("file", type=click.Path(dir_okay=False, readable=False))
@click.option("--id", "file_id", help="File id (at most 16 ASCII bytes); default: as "
                                      "send-job's, the start of FILE's name and of the "
                                      "stored content's SHA-1.")
@click.option("--job", is_flag=True, help="A print job: stored as send-job sends it (a "
                                          "slicer's G-code translated, comments dropped, "
                                          "CR line ends).")
@click.option("--raw", is_flag=True, help="With --job: G-code as it is (comments dropped), "
                                          "a slicer's not translated.")
@click.option("--head", default=HEAD_DEFAULT, show_default=True,
              help="With --job: the head a slicer's G-code is translated for.")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              default=DEFAULT_DIAMETER, show_default=True,
              help="With --job: mm, for a slicer's E in mm of filament.")
@nozzle_option
@macros_option
@valve_option
@ejection_option
@json_option
def put_cmd(image: str, file: str, file_id: str | None, job: bool, raw: bool, head: str,
            filament_diameter: float, nozzle: int | None, macros: Path | None, valve: str,
            ejection: str | None, as_json: bool) -> None:
    """Store FILE on IMAGE as a printer receives it (start, 512-byte chunks, end): byte
    for byte, or with --job as the print job send-job would send (and under the same id)."""
    if not job:
        stored = _put_as_it_is(image, file, file_id)
    else:
        from robox.gcode import Options, job_file
        from robox.gcode.files import inspect

        detected = inspect(file)
        options = None
        if not raw and (detected.from_slicer or macros is not None):
            options = Options(filament_diameter=(filament_diameter,) * 2, head=head,
                              nozzle=nozzle, macros=macros, valve=valve,
                              ejection=parse_ejection(ejection))
        with job_file(file, options, detected) as prepared:
            prepared.refuse_long_lines()
            largest = images.largest_file(image)
            if prepared.size > largest:
                raise ImageError(f"{file}: the job is {prepared.size} bytes; the largest "
                                 f"file {image} holds is {largest} bytes")
            t = prepared.translation
            if t is not None and not t.passthrough and not as_json:
                click.echo(f"translated {t.slicer} G-code ({t.e_mode} E) for a {t.head} head "
                           "(--raw stores it as it is)", err=True)
            name = default_id(Path(file).stem, prepared.sha1) if file_id is None else file_id
            with open(prepared.path, "rb") as source:
                stored = images.put_stream(image, source, name, True)
    if as_json:
        emit_json(stored)
        return
    kind = "job" if job else "file"
    click.echo(f"{image}: stored {kind} {stored['id']!r} ({stored['length']} bytes)")
    for dropped in stored["dropped"]:
        click.echo(f"{image}: dropped {dropped!r} to make room", err=True)


def _put_as_it_is(image: str, file: str, file_id: str | None) -> dict:
    """FILE stored byte for byte as a file that is not a job."""
    with open_input(file, "a file to store") as source:
        size = os.fstat(source.fileno()).st_size
        largest = images.largest_file(image)  # refused by size before it is read
        if size > largest:
            raise ImageError(f"{file}: {size} bytes; the largest file {image} holds is "
                             f"{largest} bytes")
        if file_id is None:
            digest = hashlib.sha1()
            for block in iter(lambda: source.read(1 << 16), b""):
                digest.update(block)
            source.seek(0)
            file_id = default_id(Path(file).stem, digest.hexdigest())
        return images.put_stream(image, source, file_id, False)


@sdcard.command("get")
@click.argument("image", type=click.Path(dir_okay=False, readable=False))
@click.argument("file_id", metavar="ID|NAME")
@click.option("-o", "--output", type=click.Path(dir_okay=False, readable=False),
              help="Write to this file instead of standard output.")
@yes_option
def get_cmd(image: str, file_id: str, output: str | None, yes: bool) -> None:
    """Copy the newest file with id ID from IMAGE, byte-exact. NAME, the name of a file
    put or sent without --id (part.gcode), finds the id made from it."""
    if output is not None:
        guard_output(output, (image,), "a file from the card", yes)
    data = images.get_file(image, images.resolve_id(image, file_id))
    if output is None:
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
    else:
        write_atomically(output, data)


@sdcard.command("fsck")
@click.argument("image", type=click.Path(dir_okay=False, readable=False))
@click.option("--deep", is_flag=True, help="Scan the whole card for recovery copies even "
                                           "when block 0 is valid (a mount does not).")
@json_option
def fsck_cmd(image: str, deep: bool, as_json: bool) -> None:
    """Check IMAGE: validity, what a printer would do at mount, extents, recovery copy.

    Reads what a mount reads: the whole card only when block 0 is not a valid
    directory, or with --deep. Exits 1 when a printer would format the card.
    """
    report = images.fsck_image(image, deep)
    if as_json:
        emit_json(report)
    else:
        _print_fsck(report)
    if not report["printer"]["valid"]:
        sys.exit(EXIT_PROBLEM)


def _print_fsck(report: dict) -> None:
    d = report["directory"]
    click.echo(f"image: {report['image']} ({report['capacity_blocks']} blocks)")
    click.echo(f"directory: capacity {d['capacity']}, next_write_block {d['next_write_block']}, "
               f"first_file {d['first_file']}, next_file {d['next_file']}, "
               f"last_job {d['last_job'] if d['last_job'] is not None else 'none'}")
    printer, project = report["printer"], report["project"]
    click.echo(f"printer at mount: {printer['action']}"
               + (f" ({printer['reason']})" if printer["reason"] else ""))
    click.echo(f"robox at mount: {project['action']}"
               + (f" ({project['reason']})" if project["reason"] else ""))
    for repair in project["repairs"]:
        click.echo(f"  derived: {repair}")
    if report["files"]:
        click.echo(f"files (from the {report['files_from']}):")
    for f in report["files"]:
        wraps = ", wraps" if f["wraps"] else ""
        job = "job" if f["job"] else "file"
        last = ", last job" if f["last_job"] else ""
        click.echo(f"  slot {f['slot']:>2}: {job} {f['id']!r}, {f['length']} bytes, blocks "
                   f"{f['start_block']}..{f['end_block']}{wraps}{last}")
    copy = report["recovery_copy"]
    if report["recovery_copies"] is None:
        click.echo("recovery copy: not looked for (block 0 is valid, so a mount reads none; "
                   "--deep scans the card)")
    elif copy is None:
        click.echo("recovery copy: none")
    else:
        state = "matches the directory" if copy["matches_directory"] else "differs"
        click.echo(f"recovery copy: block {copy['block']}, generation {copy['generation']}, "
                   f"{copy['files']} file(s), usable, {state}")

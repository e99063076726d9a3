"""robox-cli roboxise: a slicer's G-code made into a Robox job, offline."""

from __future__ import annotations

from pathlib import Path

import click

from robox.cli.common import emit_json, json_option
from robox.gcode import Options, roboxise_file
from robox.gcode.translate import DEFAULT_DIAMETER, HEAD_DEFAULT


@click.command("roboxise")
@click.argument("source", metavar="IN", type=click.Path(dir_okay=False, readable=False))
@click.option("-o", "--output", "target", required=True, metavar="OUT",
              type=click.Path(dir_okay=False, writable=False), help="The Robox job to write.")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              default=DEFAULT_DIAMETER, show_default=True, help="mm, for E in mm of filament.")
@click.option("--head", default=HEAD_DEFAULT, show_default=True,
              help="The head's type code (RBX01-SM, RBX01-S2, RBX01-DM, RBXDV-S1, RX...).")
@click.option("--nozzle", type=click.IntRange(0, 1),
              help="Single-material heads: nozzle 0 or 1 (default: from the slicer's nozzle "
                   "diameter, 0 below 0.6 mm).")
@click.option("--macros", type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="Directory of AutoMaker-style macros (NAME#HEAD#N0.gcode ...) for "
                   "Macro:NAME lines.")
@click.option("--no-sequences", is_flag=True,
              help="Leave out the start and end sequences (home, heat, level, purge; park, "
                   "heaters off, door unlock).")
@json_option
def roboxise_cmd(source: str, target: str, filament_diameter: float, head: str,
                 nozzle: int | None, macros: Path | None, no_sequences: bool,
                 as_json: bool) -> None:
    """Translate a slicer's G-code IN into a Robox job OUT: E to cubic millimetres, the
    needle valve for retractions, Robox temperature codes, start and end sequences."""
    options = Options(filament_diameter=(filament_diameter, filament_diameter), head=head,
                      nozzle=nozzle, macros=macros, sequences=not no_sequences)
    summary = roboxise_file(source, target, options)
    data = summary.as_dict()
    if as_json:
        emit_json(data)
        return
    if summary.passthrough:
        click.echo(f"{source}: already a Robox job ({summary.slicer}); written as it is")
    else:
        click.echo(f"{source}: {summary.slicer} G-code, E in {summary.e_mode}")
    click.echo(f"lines: {summary.lines_in} in, {summary.lines_out} out")
    for extruder, volume in summary.volume_mm3.items():
        if volume:
            click.echo(f"extruder {extruder}: {volume:.1f} mm3")
    if not summary.passthrough:
        click.echo(f"valve openings: {summary.valve_cycles}; retractions: "
                   f"{summary.retractions}; nozzle: "
                   f"{'by tool' if summary.nozzle is None else summary.nozzle}")
    if summary.macros:
        click.echo(f"macros expanded: {summary.macros}")
    dropped = ", ".join(f"{code} x{n}" for code, n in sorted(summary.dropped.items()))
    click.echo(f"dropped: {dropped or 'none'}")

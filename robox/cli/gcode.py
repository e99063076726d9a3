"""robox-cli roboxise: a slicer's G-code made into a Robox job, offline."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from robox.cli.common import EXIT_PROBLEM, emit_json, json_option
from robox.errors import UsageError
from robox.gcode import Options, roboxise_file
from robox.gcode.translate import DEFAULT_DIAMETER, HEAD_DEFAULT

nozzle_option = click.option(
    "--nozzle", type=click.IntRange(0, 1),
    help="Single-material heads: nozzle 0 or 1 throughout (default: from the slicer's "
         "nozzle diameter, 0 below 0.6 mm, and per feature from the slicer's ;WIDTH: "
         "marks where it writes them).")
macros_option = click.option(
    "--macros", type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="Directory of AutoMaker-style macros (NAME#HEAD#N0.gcode ...) for Macro:NAME "
         "lines.")


@click.command("roboxise")
@click.argument("source", metavar="IN", type=click.Path(dir_okay=False, readable=False))
@click.option("-o", "--output", "target", required=True, metavar="OUT",
              type=click.Path(dir_okay=False, writable=False), help="The Robox job to write.")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              default=DEFAULT_DIAMETER, show_default=True, help="mm, for E in mm of filament.")
@click.option("--head", default=HEAD_DEFAULT, show_default=True,
              help="The head's type code (RBX01-SM, RBX01-S2, RBX01-DM, RBXDV-S1, RX...).")
@nozzle_option
@macros_option
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
                   f"{'by tool' if summary.nozzle is None else summary.nozzle}"
                   + (f" first, {summary.nozzle_changes} changes by extrusion width"
                      if summary.nozzle_changes else ""))
    if summary.macros:
        click.echo(f"macros expanded: {summary.macros}")
    dropped = ", ".join(f"{code} x{n}" for code, n in sorted(summary.dropped.items()))
    click.echo(f"dropped: {dropped or 'none'}")


def _duration(seconds: float) -> str:
    hours, rest = divmod(round(seconds), 3600)
    minutes, secs = divmod(rest, 60)
    return (f"{hours} h " if hours else "") + f"{minutes} min {secs} s"


@click.command("simulate")
@click.argument("source", metavar="FILE", type=click.Path(dir_okay=False, readable=False))
@click.option("--head", default=HEAD_DEFAULT, show_default=True,
              help="The head's type code (RBX01-SM, RBX01-S2, RBX01-DM, RBXDV-S1, RX...).")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              default=DEFAULT_DIAMETER, show_default=True, help="mm, of the reels' filament.")
@click.option("--remaining", "remaining", type=click.FloatRange(0.0, 10_000.0),
              multiple=True, metavar="METRES",
              help="Filament left on the reels (default 240 m each); give it twice for "
                   "reels 0 and 1 of a dual-material head.")
@nozzle_option
@macros_option
@click.option("--raw", is_flag=True, help="Run FILE as it is, without translating a "
                                          "slicer's G-code.")
@json_option
@click.pass_context
def simulate_cmd(ctx: click.Context, source: str, head: str, filament_diameter: float,
                 remaining: tuple[float, ...], nozzle: int | None, macros: Path | None,
                 raw: bool, as_json: bool) -> None:
    """Print FILE on a fresh virtual printer, offline and in simulated time, and report
    the print time, the filament each extruder uses, the peak temperatures, and what
    would go wrong: moves outside the build plate, extrusion with the valve shut, a reel
    running out, the printer's errors. A slicer's file is translated first, as send-job
    does. Exit status 1 when the job would not print to its end without an error."""
    from robox.sim.simulate import Setup, simulate

    if len(remaining) > 2:
        raise UsageError("--remaining is given once (every reel) or twice (reels 0 and 1)")
    reels = (remaining * 2)[:2] if remaining else (240.0, 240.0)
    setup = Setup(head=head, filament_diameter=filament_diameter, remaining_m=reels,
                  nozzle=nozzle, macros=macros, raw=raw)
    quiet = as_json or not sys.stderr.isatty()
    with click.progressbar(length=1, label="printing (simulated)", file=sys.stderr,
                           hidden=quiet) as bar:
        def progress(line: int, total: int) -> None:
            bar.length = max(total, 1)
            bar.update(line - bar.pos)

        report = simulate(source, setup, progress)
    if as_json:
        emit_json(report.as_dict())
    else:
        _show(report)
    if report.errors or not report.completed:
        ctx.exit(EXIT_PROBLEM)


def _show(report) -> None:
    t = report.translation
    if t is None:
        click.echo(f"{report.file}: run as it is on a {report.head} head")
    else:
        click.echo(f"{report.file}: {t['slicer']} G-code, E in {t['e_mode']}, translated "
                   f"for a {report.head} head")
    rows = [("print time", _duration(report.print_time_s) + " (simulated)"),
            ("lines", f"{report.lines_run:,} of {report.lines:,} run")]
    for name, x in report.extruders.items():
        held = f", {x['reel']} holds {x['reel_remaining_m']:.1f} m" \
            if x["reel_remaining_m"] is not None else ""
        rows.append((f"extruder {name}", f"{x['mm3']:,.1f} mm3, {x['filament_m']:.2f} m of "
                                         f"{x['diameter_mm']:g} mm filament{held}"))
    rows.append(("peak", ", ".join(f"{name} {value:.1f} °C"
                                   for name, value in report.peak_c.items())))
    if report.extent_mm:
        rows.append(("extrusion", "  ".join(f"{axis} {low:.2f}..{high:.2f}" for axis, (low, high)
                                           in report.extent_mm.items()) + " mm"))
    if t is not None:
        dropped = ", ".join(f"{code} x{n}" for code, n in t["dropped"].items())
        rows.append(("dropped", dropped or "none"))
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        click.echo(f"{name:<{width}}  {value}")
    for kind, items in (("warning", report.warnings), ("error", report.errors)):
        for item in items:
            click.echo(f"{kind}: {item}")
    if not report.warnings and not report.errors:
        click.echo("no warnings, no errors")

"""robox-cli roboxise: a slicer's G-code made into a Robox job, offline."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from robox.cli.common import EXIT_PROBLEM, emit_json, guard_output, json_option, yes_option
from robox.cli.job_options import (
    ejection_option,
    macros_option,
    nozzle_option,
    parse_ejection,
    valve_option,
)
from robox.errors import UsageError
from robox.formats.heads import DEFAULT_DIAMETER, HEAD_DEFAULT


@click.command("roboxise")
@click.argument("source", metavar="IN", type=click.Path(dir_okay=False, readable=False))
@click.option("-o", "--output", "target", required=True, metavar="OUT",
              type=click.Path(dir_okay=False, writable=False),
              help="The Robox job to write (- for standard output).")
@click.option("--filament-diameter", type=click.FloatRange(0.5, 5.0),
              default=DEFAULT_DIAMETER, show_default=True, help="mm, for E in mm of filament.")
@click.option("--head", default=HEAD_DEFAULT, show_default=True,
              help="The head's type code (RBX01-SM, RBX01-S2, RBX01-DM, RBXDV-S1, RX...).")
@nozzle_option
@macros_option
@valve_option
@ejection_option
@click.option("--no-sequences", is_flag=True,
              help="Leave out the start and end sequences (home, heat, level, purge; park, "
                   "heaters off, door unlock).")
@yes_option
@json_option
def roboxise_cmd(source: str, target: str, filament_diameter: float, head: str,
                 nozzle: int | None, macros: Path | None, valve: str, ejection: str | None,
                 no_sequences: bool, yes: bool, as_json: bool) -> None:
    """Translate a slicer's G-code IN into a Robox job OUT: E to cubic millimetres, the
    needle valve for retractions, Robox temperature codes, start and end sequences."""
    from robox.fileio import is_stdout
    from robox.gcode import Options, roboxise_file

    guard_output(target, (source,), "a Robox job", yes)

    options = Options(filament_diameter=(filament_diameter, filament_diameter), head=head,
                      nozzle=nozzle, macros=macros, sequences=not no_sequences, valve=valve,
                      ejection=parse_ejection(ejection))
    summary = roboxise_file(source, target, options)
    to_stdout = is_stdout(target)  # the job on standard output: the report on stderr

    def say(text: str) -> None:
        click.echo(text, err=to_stdout)

    data = summary.as_dict()
    if as_json:
        emit_json(data, err=to_stdout)
        return
    if summary.passthrough:
        say(f"{source}: already a Robox job ({summary.slicer}); written as it is")
    else:
        say(f"{source}: {summary.slicer} G-code, E in {summary.e_mode}")
    say(f"lines: {summary.lines_in} in, {summary.lines_out} out")
    for extruder, volume in summary.volume_mm3.items():
        if volume:
            say(f"extruder {extruder}: {volume:.1f} mm3")
    if not summary.passthrough:
        say(f"valve openings: {summary.valve_cycles}; retractions: "
                   f"{summary.retractions}; nozzle: "
                   f"{'by tool' if summary.nozzle is None else summary.nozzle}"
                   + (f" first, {summary.nozzle_changes} changes by extrusion width"
                      if summary.nozzle_changes else ""))
    if summary.macros:
        say(f"macros expanded: {summary.macros}")
    dropped = ", ".join(f"{code} x{n}" for code, n in sorted(summary.dropped.items()))
    say(f"dropped: {dropped or 'none'}")


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
@valve_option
@ejection_option
@click.option("--raw", is_flag=True, help="Run FILE as it is, without translating a "
                                          "slicer's G-code.")
@click.option("--plot", "plot_path", metavar="FILE.png",
              type=click.Path(dir_okay=False, writable=False),
              help="Draw a layer from above: paths coloured by the plastic they got "
                   "against what was driven for them, blobs circled, travels faint.")
@click.option("--layer", type=click.IntRange(1), metavar="N",
              help="The layer --plot draws (from 1; default: the layer of the worst place).")
@json_option
@click.pass_context
def simulate_cmd(ctx: click.Context, source: str, head: str, filament_diameter: float,
                 remaining: tuple[float, ...], nozzle: int | None, macros: Path | None,
                 valve: str, ejection: str | None, raw: bool, plot_path: str | None,
                 layer: int | None, as_json: bool) -> None:
    """Print FILE on a fresh virtual printer, offline and in simulated time, and report
    the print time, the filament each extruder uses, the peak temperatures, and what
    would go wrong: moves outside the build plate, extrusion with the valve shut, a reel
    running out, the printer's errors. A slicer's file is translated first, as send-job
    does. Exit status 1 when the job would not print to its end without an error."""
    from robox.sim.simulate import Setup, simulate

    if len(remaining) > 2:
        raise UsageError("--remaining is given once (every reel) or twice (reels 0 and 1)")
    reels = (remaining * 2)[:2] if remaining else (240.0, 240.0)
    if layer is not None and plot_path is None:
        raise UsageError("--layer goes with --plot")
    if plot_path is not None:
        require_png_target(plot_path)
    setup = Setup(head=head, filament_diameter=filament_diameter, remaining_m=reels,
                  nozzle=nozzle, macros=macros, raw=raw, valve=valve,
                  ejection=parse_ejection(ejection))
    quiet = as_json or not sys.stderr.isatty()
    with click.progressbar(length=1, label="printing (simulated)", file=sys.stderr,
                           hidden=quiet) as bar:
        def progress(line: int, total: int) -> None:
            bar.length = max(total, 1)
            bar.update(line - bar.pos)

        drawn: list[int] = []
        report = simulate(source, setup, progress, None if plot_path is None else
                          lambda report: drawn.append(draw(report, plot_path, layer)))
    if as_json:
        emit_json(report.as_dict())
    else:
        _show(report)
        if drawn:
            click.echo(f"plot: layer {drawn[0]} drawn in {plot_path}")
    if report.errors or not report.completed:
        ctx.exit(EXIT_PROBLEM)


def require_png_target(path: str) -> None:
    """Refuse at once a --plot target that cannot be written (before the print runs)."""
    target = Path(path)
    if not target.name.lower().endswith(".png"):
        raise UsageError(f"--plot {path}: the picture is a PNG file (FILE.png)")
    if not target.resolve().parent.is_dir():
        raise UsageError(f"--plot {path}: no directory {target.parent}")


def draw(report, path: str, layer: int | None) -> int:
    """The --plot picture, written whole or not at all."""
    import io

    from robox.fileio import write_atomically
    from robox.sim.quality import plot

    if report.quality is None:
        raise UsageError("--plot: the simulation recorded no plastic")
    buffer = io.BytesIO()
    worst = sorted(report.quality_worst, key=lambda p: -p.mm3)
    try:
        drawn = plot(report.quality, buffer, layer, worst, Path(report.file).name)
    except ValueError as e:
        raise UsageError(f"--plot: {e}") from None
    write_atomically(path, buffer.getvalue())
    return drawn


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
    d = report.deposition
    if d is not None:
        rows.append(("path ends", f"{d['path_ends']:,} on the plate ({d['opens']:,} opens, "
                                  f"{d['layers']} layers)"))
        rows.append(("blobs", f"{d['blob_mm3']:.3f} mm3 left standing still "
                              f"({d['blob_mm3_per_path_end']:.3f} mm3 per path end)"))
        rows.append(("starved", f"{d['starved_mm']:.1f} mm of path below 80% of its plastic "
                                f"({d['starved_mm_per_open']:.2f} mm per open)"))
        for i, w in enumerate(d["worst"], 1):
            what = (f"blob of {w['mm3']:.3f} mm3" if w["kind"] == "blob" else
                    f"{w['length_mm']:.1f} mm starved, {w['mm3']:.3f} mm3 short")
            rows.append((f"worst {i}", f"{what} at X {w['x']:.1f} Y {w['y']:.1f}, layer "
                                       f"{w['layer']}, job line {w['line']}"))
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        click.echo(f"{name:<{width}}  {value}")
    for kind, items in (("warning", report.warnings), ("error", report.errors)):
        for item in items:
            click.echo(f"{kind}: {item}")
    if not report.warnings and not report.errors:
        click.echo("no warnings, no errors")

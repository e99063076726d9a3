"""The options that say how a slicer's file is made into a Robox job, shared by every
command that translates one (roboxise, simulate, send-job, sdcard put). Apart from
those commands, so that a printer command's module loads without the offline ones."""

from __future__ import annotations

from pathlib import Path

import click

from robox.errors import UsageError

nozzle_option = click.option(
    "--nozzle", type=click.IntRange(0, 1),
    help="Single-material heads: nozzle 0 or 1 throughout (default: from the slicer's "
         "nozzle diameter, 0 below 0.6 mm, and per feature from the slicer's ;WIDTH: "
         "marks where it writes them).")
valve_option = click.option(
    "--valve", type=click.Choice(["automaker", "simple"]), default="automaker",
    show_default=True,
    help="How a slicer's file drives the needle valve: 'automaker' closes on the move "
         "over each path's last ejection volume and refills on every open, as AutoMaker "
         "did; 'simple' shuts and opens standing still (for comparison).")
ejection_option = click.option(
    "--ejection", metavar="MM3[,MM3]",
    help="The needle's ejection volume per nozzle (default: the head's, e.g. 0.3,0.6 "
         "on RBX01-SM).")


def parse_ejection(text: str | None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise UsageError(f"--ejection {text!r}: give one or two volumes in mm3, "
                         "e.g. 0.3,0.6") from None
    if not 1 <= len(values) <= 2 or any(not 0.01 <= v <= 50.0 for v in values):
        raise UsageError(f"--ejection {text!r}: one or two volumes of 0.01 to 50 mm3")
    return values


macros_option = click.option(
    "--macros", type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="Directory of AutoMaker-style macros (NAME#HEAD#N0.gcode ...) for Macro:NAME "
         "lines.")

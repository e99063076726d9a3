"""robox-cli: parse, call, format, exit codes. Nothing else."""

from __future__ import annotations

import logging

import click

from robox import __version__
from robox.cli.common import RoboxGroup
from robox.cli.eeprom import eeprom
from robox.cli.firmware import firmware
from robox.cli.gcode import roboxise_cmd, simulate_cmd
from robox.cli.printer import COMMANDS
from robox.cli.sdcard import sdcard
from robox.cli.sim import sim


def _show_version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    from robox.native import describe  # imports the model's modules: only when asked

    click.echo(f"robox-cli, version {__version__}; firmware model: {describe()}")
    ctx.exit()


@click.group(cls=RoboxGroup)
@click.option("--version", is_flag=True, expose_value=False, is_eager=True,
              callback=_show_version,
              help="Show the version and whether the firmware model runs compiled, and exit.")
@click.option("--device", envvar="ROBOX_DEVICE", metavar="DEVICE",
              help="usb (the one attached Robox), usb:ID (unique-ID prefix), serial:PATH, "
                   "sim[:DIR] (the virtual printer, served in the background), sim-once[:DIR] "
                   "(the virtual printer in this process, for one command). Default: "
                   "$ROBOX_DEVICE, else usb.")
@click.option("--timeout", type=click.FloatRange(0.1, 3600.0), default=10.0,
              envvar="ROBOX_TIMEOUT", show_default=True, metavar="SECONDS",
              help="How long the printer may take to begin a reply. Default: $ROBOX_TIMEOUT, "
                   "else 10.")
@click.option("-v", "--verbose", count=True,
              help="Log the wire on stderr: -v each command and reply, -vv their bytes.")
@click.pass_context
def cli(ctx: click.Context, device: str | None, timeout: float, verbose: int) -> None:
    """Drive a CEL Robox printer, its virtual twin, and its card, EEPROM and firmware images."""
    ctx.obj = {"device": device, "timeout": timeout}
    wire = logging.getLogger("robox.wire")
    wire.handlers.clear()  # one command's settings, even when called again in one process
    wire.propagate = False
    wire.setLevel(logging.WARNING)
    if verbose:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("robox-cli: %(message)s"))
        wire.addHandler(handler)
        wire.setLevel(logging.DEBUG if verbose > 1 else logging.INFO)


cli.add_command(sdcard)
cli.add_command(eeprom)
cli.add_command(firmware)
cli.add_command(sim)
cli.add_command(roboxise_cmd)
cli.add_command(simulate_cmd)
for command in COMMANDS:
    cli.add_command(command)


def main() -> None:
    from robox.launch import main as launch

    launch()

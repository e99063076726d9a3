"""robox-cli: parse, call, format, exit codes. Nothing else."""

from __future__ import annotations

import importlib

import click

from robox import __version__
from robox.cli.common import RoboxGroup
from robox.launch import main as launch
from robox.launch import start_up_over

#: Each command, where it is defined, and the first sentence of its help: a command's
#: module is imported only when the command runs (or its own help is asked for), so
#: `robox-cli --help` and a printer command start without the firmware model or the
#: translator (tests/cli check this table against the commands).
LAZY_COMMANDS = {
    "abort": ("robox.cli.printer", "abort_cmd",
              "Abort the job and switch the heaters off (with no job, the heaters only)."),
    "calibrate": ("robox.cli.maintenance", "calibrate",
                  "Calibrate the head: nozzle heights, needle openings, X/Y alignment."),
    "eject-stuck": ("robox.cli.maintenance", "eject_stuck_cmd",
                    "Free filament stuck in the head: heat, push through, cool and pull it "
                    "out."),
    "eeprom": ("robox.cli.eeprom", "eeprom",
               "Build, inspect and change head and reel EEPROM dumps."),
    "errors": ("robox.cli.printer", "errors_cmd",
               "Show the printer's latched errors (and clear them with --clear)."),
    "files": ("robox.cli.printer", "files_cmd",
              "List the files on the printer's SD card, oldest first."),
    "firmware": ("robox.cli.firmware", "firmware",
                 "Firmware images: insert and verify anti-checksums, convert for the SD "
                 "card."),
    "format-eeprom": ("robox.cli.printer", "format_eeprom_cmd",
                      "Format (zero) a head or reel EEPROM: its calibration or filament "
                      "data is lost."),
    "gcode": ("robox.cli.printer", "gcode_cmd",
              "Send G-code lines; prints the response of reporting codes (M105, M114, "
              "...)."),
    "head-change": ("robox.cli.maintenance", "head_change_cmd",
                    "Change the head: unload, park at the front and unlock, then read the "
                    "new one."),
    "level-gantry": ("robox.cli.maintenance", "level_gantry_cmd",
                     "Level the gantry from the Z switch at each leadscrew."),
    "load": ("robox.cli.maintenance", "load_cmd",
             "Load a feed: push the filament in until the drive takes it; the printer does "
             "the rest."),
    "pause": ("robox.cli.printer", "pause_cmd", "Pause the job (the head parks)."),
    "purge": ("robox.cli.maintenance", "purge_cmd",
              "Purge the old material out of the nozzle(s) after a material change."),
    "printers": ("robox.cli.printer", "printers_cmd",
                 "List the Robox printers attached over USB and the virtual printers "
                 "being served."),
    "read-eeprom": ("robox.cli.printer", "read_eeprom_cmd",
                    "Read a head or reel EEPROM and show its fields."),
    "reel": ("robox.cli.reel", "reel",
             "Filament reels: program a reel's EEPROM for any filament, and read one "
             "back."),
    "reset": ("robox.cli.printer", "reset_cmd",
              "Reset the printer (as switching it off and on, keeping the power)."),
    "resume": ("robox.cli.printer", "resume_cmd", "Resume a paused job."),
    "roboxise": ("robox.cli.gcode", "roboxise_cmd",
                 "Translate a slicer's G-code IN into a Robox job OUT: E to cubic "
                 "millimetres, the needle valve for retractions, Robox temperature codes, "
                 "start and end sequences."),
    "run-job": ("robox.cli.printer", "run_job_cmd",
                "Print a job already on the card (no ID: the last job run)."),
    "sdcard": ("robox.cli.sdcard", "sdcard",
               "Build and inspect SD card images (the printer's circular file system)."),
    "send-job": ("robox.cli.printer", "send_job_cmd",
                 "Upload FILE to the SD card and print it (printing starts after the "
                 "second chunk)."),
    "sim": ("robox.cli.sim", "sim",
            "Run the virtual printer (the firmware model on simulated hardware)."),
    "simulate": ("robox.cli.gcode", "simulate_cmd",
                 "Print FILE on a fresh virtual printer, offline and in simulated time, "
                 "and report the print time, the filament each extruder uses, the peak "
                 "temperatures, and what would go wrong: moves outside the build plate, "
                 "extrusion with the valve shut, a reel running out, the printer's "
                 "errors."),
    "status": ("robox.cli.printer", "status_cmd", "Show the printer's status report."),
    "unload": ("robox.cli.maintenance", "unload_cmd",
               "Unload a feed's filament: the printer heats, moves right and pulls it back."),
    "update-firmware": ("robox.cli.printer", "update_firmware_cmd",
                        "Verify BIN, upload it, flash it, and check the printer comes "
                        "back."),
    "write-eeprom": ("robox.cli.printer", "write_eeprom_cmd",
                     "Change fields of a head or reel EEPROM."),
}


class LazyGroup(RoboxGroup):
    """The top-level group: its commands imported as they are used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(LAZY_COMMANDS))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        command = super().get_command(ctx, name)
        if command is None and name in LAZY_COMMANDS:
            module, attribute, _ = LAZY_COMMANDS[name]
            command = getattr(importlib.import_module(module), attribute)
            self.add_command(command, name)
        start_up_over()
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list from the table: no command's module is imported for it."""
        names = self.list_commands(ctx)
        if not names:
            return
        limit = formatter.width - 6 - max(len(name) for name in names)
        rows = []
        for name in names:
            if name in self.commands:
                rows.append((name, self.commands[name].get_short_help_str(limit)))
            else:
                rows.append((name, click.utils.make_default_short_help(
                    LAZY_COMMANDS[name][2], limit)))
        with formatter.section("Commands"):
            formatter.write_dl(rows)


def _show_version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    from robox.native import describe  # imports the model's modules: only when asked

    click.echo(f"robox-cli, version {__version__}; firmware model: {describe()}")
    ctx.exit()


@click.group(cls=LazyGroup)
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
@click.option("--wait-lock", type=click.FloatRange(0.0, 86400.0), default=0.0,
              envvar="ROBOX_WAIT_LOCK", metavar="SECONDS",
              help="Wait up to SECONDS for a printer, port, image or dump another program "
                   "is using, instead of refusing at once. Default: $ROBOX_WAIT_LOCK, "
                   "else 0.")
@click.pass_context
def cli(ctx: click.Context, device: str | None, timeout: float, verbose: int,
        wait_lock: float) -> None:
    """Drive a CEL Robox printer, its virtual twin, and its card, EEPROM and firmware images."""
    import sys

    from robox.locks import set_wait

    set_wait(wait_lock)  # one command's setting, even when called again in one process
    ctx.obj = {"device": device, "timeout": timeout}
    if not verbose and "logging" not in sys.modules:
        return  # no logger set up, nor one to undo: logging need not load (start-up)
    import logging

    wire = logging.getLogger("robox.wire")
    wire.handlers.clear()  # one command's settings, even when called again in one process
    wire.propagate = False
    wire.setLevel(logging.WARNING)
    if verbose:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("robox-cli: %(message)s"))
        wire.addHandler(handler)
        wire.setLevel(logging.DEBUG if verbose > 1 else logging.INFO)



def main() -> None:
    launch()

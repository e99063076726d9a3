"""robox-cli starts light: a command's module is imported only when the command runs,
and `--help` lists them all from a table (src/robox/cli/__init__.py)."""

import gc
import subprocess
import sys

import click
import pytest

from robox.cli import LAZY_COMMANDS, cli

HEAVY = ("robox.firmware.main", "robox.gcode.translate", "robox.sim.printer", "matplotlib")


@pytest.mark.parametrize("limit", [45, 80, 200])
def test_the_tables_help_is_each_commands_own(limit):
    ctx = click.Context(cli)
    for name, (_module, _attribute, text) in LAZY_COMMANDS.items():
        command = cli.get_command(ctx, name)
        assert command is not None and command.name == name
        assert click.utils.make_default_short_help(text, limit) == \
            command.get_short_help_str(limit), name
    assert set(cli.list_commands(ctx)) == set(LAZY_COMMANDS)


def loaded_after(*args: str) -> set[str]:
    """The modules a fresh interpreter has loaded once robox-cli ran `args`."""
    probe = ("import sys\nfrom robox.cli import cli\n"
             "try:\n    cli.main(list(sys.argv[1:]), standalone_mode=False)\n"
             "except BaseException:\n    pass\n"
             "print('\\n'.join(sorted(sys.modules)))\n")
    out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True,
                         text=True, check=True, timeout=60)
    return set(out.stdout.split())


@pytest.mark.parametrize("args", [("--help",), ("status",), ("sdcard", "--help")])
def test_a_command_loads_neither_the_model_nor_the_translator(args):
    loaded = loaded_after(*args)
    assert not [name for name in HEAVY if name in loaded]
    assert ("robox.cli.printer" in loaded) == (args == ("status",))


def test_status_of_the_served_printer_loads_neither_the_model_nor_the_translator(tmp_path):
    """The served printer's model runs in its server: a command to it finds the server by
    its state directory and talks over the pty, without loading the model; nor does
    `sim --help` (its module names the default state directory)."""
    from tests.sim import serving

    state = tmp_path / "printer"
    with serving.served(state):
        loaded = loaded_after("--device", f"sim:{state}", "status")
        loaded_sim = loaded_after("sim", "--help")
    assert "robox.cli.printer" in loaded and "robox.host.devices" in loaded
    assert not [name for name in HEAVY if name in loaded]
    assert not [name for name in HEAVY if name in loaded_sim]
    # nor what status does not use: the upload catalogue, EEPROM fields, firmware images,
    # the card's layout (a file's id is robox.formats.card_file), logging (nothing logs),
    # the offline translating commands (their options are robox.cli.job_options), and
    # neither pyserial (the printer is reached at its socket) nor the socket module's
    # enums (the socket is made by _socket); nor the heads' table (send-job's
    # translation options) nor shlex (the hint after an interrupted upload)
    assert not {"robox.host.catalogue", "robox.formats.eeprom", "robox.formats.firmware",
                "hashlib", "robox.formats.sdcard", "logging", "robox.cli.gcode", "serial",
                "socket", "robox.formats.heads", "shlex"} & loaded


WIRE_LINE = "sent 0xb0 (1 bytes), got 0xe1 (222 bytes)"


def test_the_wire_is_logged_once_logging_is_set_up_however_late(tmp_path):
    """Logging loads only when wanted (-v, or a program that set it up), and then the
    exchanges are logged, even when it was set up after robox's client was loaded."""
    from tests.sim import serving

    state = tmp_path / "printer"
    late = ("import sys\nfrom robox.host.devices import open_printer\n"
            "with open_printer(sys.argv[1]) as printer:\n"
            "    printer.status()\n"
            "    assert 'logging' not in sys.modules\n"
            "    import logging\n"
            "    logging.basicConfig(level=logging.INFO, format='%(name)s: %(message)s')\n"
            "    printer.status()\n")
    with serving.served(state):
        verbose = subprocess.run(
            [sys.executable, "-m", "robox.cli", "-v",
             "--device", f"sim:{state}", "status"],
            capture_output=True, text=True, timeout=60)
        library = subprocess.run([sys.executable, "-c", late, f"sim:{state}"],
                                 capture_output=True, text=True, timeout=60)
    assert verbose.returncode == 0, verbose.stderr
    assert f"robox-cli: {WIRE_LINE}" in verbose.stderr.splitlines()
    assert library.returncode == 0, library.stderr
    assert library.stderr.splitlines().count(f"robox.wire: {WIRE_LINE}") == 1


@pytest.mark.parametrize(("args", "on"), [(("--help",), False), (("sdcard", "--help"), True)])
def test_the_collector_is_off_for_the_start_up_and_on_for_the_command(args, on):
    """robox-cli's imports run with the cyclic collector off; once a command's module is
    loaded, what they made is frozen and the collector is on again (src/robox/launch.py).
    `--help` loads no command's module: the process ends first."""
    probe = ("import atexit, gc, sys\n"
             "atexit.register(lambda: print(gc.isenabled(), gc.get_freeze_count() > 0,"
             " file=sys.stderr))\n"
             "sys.argv = ['robox-cli', *sys.argv[1:]]\n"
             "from robox.launch import main\n"
             "main()\n")
    out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stderr.split()[-2:] == [str(on), str(on)]


def test_a_program_running_the_command_line_keeps_its_collector_as_it_has_it(capsys):
    frozen = gc.get_freeze_count()
    gc.disable()
    try:
        cli.main(["sdcard", "--help"], standalone_mode=False)
        assert not gc.isenabled()
    finally:
        gc.enable()
    cli.main(["sdcard", "--help"], standalone_mode=False)
    assert gc.isenabled() and gc.get_freeze_count() == frozen
    assert "Usage:" in capsys.readouterr().out

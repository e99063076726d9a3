"""robox-cli sim: the virtual printer."""

from __future__ import annotations

import os
import time
from pathlib import Path

import click

from robox.cli.common import emit_json, json_option, number_pair
from robox.errors import UsageError
from robox.sim.served import default_state_dir

STATE_OPTION = click.option("--state", "state_dir", type=click.Path(file_okay=False),
                            help="State directory (default: the per-user virtual printer).")


def flaw_options(f):
    """The head's true build, for `sim serve` and `sim head`."""
    for option in reversed((
            click.option("--nozzle-z-difference", "z_difference", type=float, metavar="MM",
                         help="Nozzle 1's tip sits MM lower than nozzle 0's (negative: "
                              "higher); the Z probe finds it."),
            click.option("--b-open", "b_open", callback=number_pair, metavar="B0,B1",
                         help="The B positions where nozzle 0's needle (positive) and "
                              "nozzle 1's (negative) just open; the valve follows them."),
            click.option("--xy-offset", "xy_offset", callback=number_pair, metavar="DX,DY",
                         help="Nozzle 1 sits DX, DY mm from where the head's EEPROM puts "
                              "it, relative to nozzle 0."))):
        f = option(f)
    return f


def _edit_flaws(directory: Path, z_difference, b_open, xy_offset, perfect: bool = False,
                who: str = "sim head") -> dict:
    """Record the head's true build in the state directory, under its lock."""
    from robox.locks import DirectoryLock
    from robox.sim.printer import check_flaws, create_state, read_flaws, write_flaws

    create_state(directory)
    lock = DirectoryLock(directory, who)
    try:
        flaws = {} if perfect else read_flaws(directory)
        for key, value in (("nozzle_z_difference_mm", z_difference), ("b_open", b_open),
                           ("xy_offset_mm", xy_offset)):
            if value is not None:
                flaws[key] = value
        try:
            flaws = check_flaws(flaws)
        except ValueError as e:
            raise UsageError(f"virtual head: {e}") from None
        write_flaws(directory, flaws)
    finally:
        lock.release()
    return flaws


def _directory(state_dir: str | None) -> Path:
    """The state directory: --state, else the one `--device sim:DIR` (or sim-once:DIR,
    or $ROBOX_DEVICE) names, else the per-user virtual printer's."""
    from click.core import ParameterSource

    from robox.host.devices import ENVIRONMENT

    ctx = click.get_current_context(silent=True)
    root = ctx.find_root() if ctx is not None else None
    device = ((root.obj or {}).get("device") if root is not None else None) or \
        os.environ.get(ENVIRONMENT) or ""
    kind, _, rest = device.partition(":")
    named = Path(os.path.abspath(rest)) if kind in ("sim", "sim-once") and rest else None
    if state_dir:  # it wins over $ROBOX_DEVICE; a --device that names another is refused
        chosen = Path(os.path.abspath(state_dir))
        typed = root is not None and \
            root.get_parameter_source("device") == ParameterSource.COMMANDLINE
        if named is not None and named != chosen and typed:
            raise UsageError(f"--device {device} and --state {state_dir} name two printers; "
                             "give one")
        return chosen
    return named if named is not None else default_state_dir()


@click.group()
def sim() -> None:
    """Run the virtual printer (the firmware model on simulated hardware)."""


@sim.command("serve")
@STATE_OPTION
@click.option("--realtime", is_flag=True, help="Pace simulated time to the wall clock.")
@click.option("--speed", type=float, help="Pace simulated time at FACTOR times the wall clock.")
@click.option("--detach", is_flag=True,
              help="Serve in the background; print the pseudo-terminal's path and return.")
@flaw_options
def serve_cmd(state_dir: str | None, realtime: bool, speed: float | None,
              detach: bool, z_difference, b_open, xy_offset) -> None:
    """Serve the virtual printer on a pseudo-terminal; its path is the first line printed.

    Without --realtime or --speed the clock runs as fast as the work needs. Stops on
    SIGINT or SIGTERM (`robox-cli sim stop`), leaving the state files consistent. One
    state directory is served by one process at a time. The head options record its
    true build in the state first (as `sim head` does).
    """
    from robox.sim import served
    from robox.sim.serve import serve_forever

    if realtime and speed is not None:
        raise UsageError("give --realtime or --speed, not both")
    if speed is not None and speed <= 0:
        raise UsageError("--speed must be positive")
    pace = 1.0 if realtime else speed
    directory = _directory(state_dir)
    if (z_difference, b_open, xy_offset) != (None, None, None):
        _edit_flaws(directory, z_difference, b_open, xy_offset, who="sim serve")
    if detach:
        record = served.start(directory, pace)
        click.echo(record["pty"])
        click.echo(f"serving the virtual printer for {directory} in the background "
                   f"(PID {record['pid']}); {served.stop_hint(directory)} switches it off",
                   err=True)
        return
    serve_forever(directory, pace, lambda path: click.echo(path),
                  lambda message: click.echo(message, err=True))


@sim.command("status")
@STATE_OPTION
@json_option
def status_cmd(state_dir: str | None, as_json: bool) -> None:
    """Say whether the virtual printer is served, by which process, on which port.

    Exits 0 when it is served, 3 when it is not.
    """
    from robox.sim import served

    directory = _directory(state_dir)
    record = served.served_record(directory)
    data = {"state": str(directory), "served": record is not None}
    if record is not None:
        data.update(pid=record.get("pid"), pty=record.get("pty"), link=record.get("link"),
                    started=record.get("started"), speed=record.get("speed"))
    if as_json:
        emit_json(data)
    elif record is None:
        click.echo(f"not served: {directory}")
    else:
        since = record.get("started")
        up = f", up {_duration(time.time() - since)}" if isinstance(since, (int, float)) else ""
        pace = record.get("speed")
        clock = "as fast as the work needs" if pace is None else f"at {pace:g}x real time"
        click.echo(f"served on {record.get('pty') or '(starting)'} by PID {record.get('pid')}"
                   f"{up}; clock {clock}; state {directory}")
    if record is None:
        raise SystemExit(3)


@sim.command("stop")
@STATE_OPTION
@json_option
def stop_cmd(state_dir: str | None, as_json: bool) -> None:
    """Switch off the served virtual printer; it saves its state first."""
    from robox.sim import served

    directory = _directory(state_dir)
    record = served.stop(directory)
    if as_json:
        emit_json({"state": str(directory), "stopped": record is not None,
                   "pid": record.get("pid") if record else None})
    elif record is None:
        click.echo(f"not served: {directory}")
    else:
        click.echo(f"stopped the virtual printer (PID {record.get('pid')}); state {directory}")


@sim.command("load")
@STATE_OPTION
@click.option("--feed", type=click.Choice(["E", "D", "both"]), default="E",
              show_default=True, help="The feed to load (D: reel 1 on a dual-material head).")
@click.option("--metres", type=click.FloatRange(0.001, 10_000.0), default=240.0,
              show_default=True, help="Filament in the feed, from its tip back.")
@click.option("--at", "where", type=click.Choice(["nozzle", "drive"]), default="nozzle",
              show_default=True,
              help="Where its tip is: at the nozzle (ready to print) or just in the drive.")
@json_option
def load_cmd(state_dir: str | None, feed: str, metres: float, where: str,
             as_json: bool) -> None:
    """Put filament in the virtual printer's feeds, as a loaded printer has.

    Recorded in the state directory (filament.json) and taken by the printer the next
    time it is switched on (`sim serve`, `--device sim`, `sim-once:DIR`); a printer
    being served is refused: `robox-cli sim stop` it first. At power-up a new virtual
    printer has empty feeds, as the spec says."""
    from robox.sim.printer import NOZZLE_MM

    tip = NOZZLE_MM if where == "nozzle" else 0.0
    _edit_feeds(_directory(state_dir), feed, {"length_mm": metres * 1000.0, "tip_mm": tip},
                as_json)


@sim.command("unload")
@STATE_OPTION
@click.option("--feed", type=click.Choice(["E", "D", "both"]), default="both",
              show_default=True)
@json_option
def unload_cmd(state_dir: str | None, feed: str, as_json: bool) -> None:
    """Take the filament out of the virtual printer's feeds (see `sim load`)."""
    _edit_feeds(_directory(state_dir), feed, None, as_json)


@sim.command("head")
@STATE_OPTION
@flaw_options
@click.option("--perfect", is_flag=True, help="Forget every flaw first: the head exactly "
                                               "as its EEPROM says.")
@json_option
def head_cmd(state_dir, z_difference, b_open, xy_offset, perfect, as_json) -> None:
    """Give the virtual printer's head true imperfections, or show them.

    A real head's nozzles are not where its EEPROM says until it is calibrated; these
    make the virtual one so: the Z probe, the valve and the printed alignment pattern
    follow them, and `robox-cli calibrate` measures them. Recorded in the state
    directory (flaws.json) and taken at the next power-up; a printer being served is
    refused (`robox-cli sim stop` it first)."""
    flaws = _edit_flaws(_directory(state_dir), z_difference, b_open, xy_offset, perfect)
    if as_json:
        emit_json({"state": str(_directory(state_dir)), "flaws": flaws})
        return
    if not flaws:
        click.echo("head: perfect (as its EEPROM says)")
    if "nozzle_z_difference_mm" in flaws:
        click.echo(f"nozzle 1's tip {flaws['nozzle_z_difference_mm']:g} mm below nozzle 0's")
    if "b_open" in flaws:
        b0, b1 = flaws["b_open"]
        click.echo(f"needles open at B {b0:g} (nozzle 0) and {b1:g} (nozzle 1)")
    if "xy_offset_mm" in flaws:
        dx, dy = flaws["xy_offset_mm"]
        click.echo(f"nozzle 1 off by X {dx:g} mm, Y {dy:g} mm")


def _edit_feeds(directory: Path, feed: str, value: dict | None, as_json: bool) -> None:
    """Set the state directory's filament record for `feed`, under its lock (a served
    printer's directory is refused with the PID that has it)."""
    from robox.locks import DirectoryLock
    from robox.sim.printer import create_state, read_filament, write_filament

    create_state(directory)
    lock = DirectoryLock(directory, "sim load")
    try:
        feeds = read_filament(directory)
        for name in ("E", "D") if feed == "both" else (feed,):
            feeds[name] = value
        write_filament(directory, feeds)
    finally:
        lock.release()
    if as_json:
        emit_json({"state": str(directory), "filament": feeds})
        return
    for name, f in feeds.items():
        text = "empty" if f is None else \
            f"{f['length_mm'] / 1000.0:g} m, tip {f['tip_mm']:g} mm along the path"
        click.echo(f"feed {name}: {text}")


def _duration(seconds: float) -> str:
    seconds = max(0, int(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, seconds = divmod(rest, 60)
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{seconds:02d}s"

"""robox-cli sim: the virtual printer."""

from __future__ import annotations

from pathlib import Path

import click

from robox.errors import UsageError
from robox.sim.printer import default_state_dir


@click.group()
def sim() -> None:
    """Run the virtual printer (the firmware model on simulated hardware)."""


@sim.command("serve")
@click.option("--state", "state_dir", type=click.Path(file_okay=False),
              help="State directory (default: the per-user virtual printer).")
@click.option("--realtime", is_flag=True, help="Pace simulated time to the wall clock.")
@click.option("--speed", type=float, help="Pace simulated time at FACTOR times the wall clock.")
def serve_cmd(state_dir: str | None, realtime: bool, speed: float | None) -> None:
    """Serve the virtual printer on a pseudo-terminal; its path is the first line printed.

    Without --realtime or --speed the clock runs as fast as the work needs. Stops on
    SIGINT or SIGTERM, leaving the state files consistent.
    """
    from robox.sim.serve import serve_forever

    if realtime and speed is not None:
        raise UsageError("give --realtime or --speed, not both")
    if speed is not None and speed <= 0:
        raise UsageError("--speed must be positive")
    pace = 1.0 if realtime else speed
    directory = Path(state_dir) if state_dir else default_state_dir()
    serve_forever(directory, pace, lambda path: click.echo(path),
                  lambda message: click.echo(message, err=True))

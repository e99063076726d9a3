#!/usr/bin/env python3
"""robox-cli's start-up: how long a command takes beyond the interpreter's own start.

Usage: python bench/startup.py [--rounds N]

Each command runs in its own process through the installed `robox-cli` script, as a
user types it: `robox-cli --help`, and `robox-cli --device sim:DIR status` to a virtual
printer served in the background (`sim serve --detach`, started first: the figure is a
command's, not the server's start). Beside them, the interpreter alone (`python -c
pass`). They run in rounds (default 21), one of each per round, so that whatever else
the machine does falls on each alike.

For each: the median and the least wall time and CPU time (the child's own, from
wait4), and its time beyond the interpreter's, the median over the rounds of the
difference within a round. Then, from one run of each command under `python -X
importtime`, the modules it imported at the top level that took 2 ms or more (their
cumulative time; importtime's own bookkeeping makes every figure there a little
larger). Asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from robox.native import build


def robox_cli_script() -> str:
    """The installed robox-cli script: beside this interpreter (a virtual environment's
    bin), else on the PATH."""
    beside = Path(sys.executable).with_name("robox-cli")
    if beside.exists():
        return str(beside)
    found = shutil.which("robox-cli")
    if found is None:
        raise SystemExit("bench/startup.py: no robox-cli script beside the interpreter or "
                         "on the PATH (install the package first)")
    return found


def timed(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU milliseconds of one run of `argv` (its output thrown away)."""
    start = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"bench/startup.py: {' '.join(argv)} failed")
    return wall * 1000, (usage.ru_utime + usage.ru_stime) * 1000


def top_imports(argv: list[str], least_ms: float = 2.0) -> list[tuple[float, str]]:
    """The top-level imports of one run of `argv` under -X importtime that took at least
    `least_ms` (cumulative), largest first."""
    child = subprocess.run([sys.executable, "-X", "importtime", *argv], capture_output=True,
                           text=True)
    found = []
    for line in child.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cumulative, name = line.split("|", 2)
        if name.startswith(" ") and not name.startswith("  ") and cumulative.strip().isdigit():
            ms = int(cumulative) / 1000
            if ms >= least_ms:
                found.append((ms, name.strip()))
    return sorted(found, reverse=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=21)
    rounds = parser.parse_args().rounds
    script = robox_cli_script()
    print(f"measuring {build()}, through {script}")
    with tempfile.TemporaryDirectory() as tmp:
        state = str(Path(tmp) / "printer")
        subprocess.run([script, "sim", "serve", "--state", state, "--detach"], check=True,
                       capture_output=True)
        try:
            commands = {
                "interpreter (python -c pass)": [sys.executable, "-c", "pass"],
                "robox-cli --help": [script, "--help"],
                "robox-cli status (served printer)": [script, "--device", f"sim:{state}",
                                                      "status"],
            }
            for argv in commands.values():
                timed(argv)  # once each first: the files in the page cache
            walls: dict[str, list[float]] = {name: [] for name in commands}
            cpus: dict[str, list[float]] = {name: [] for name in commands}
            for _ in range(rounds):
                for name, argv in commands.items():
                    wall, cpu = timed(argv)
                    walls[name].append(wall)
                    cpus[name].append(cpu)
            imports = {name: top_imports(argv) for name, argv in commands.items()
                       if argv[0] == script}
        finally:
            subprocess.run([script, "sim", "stop", "--state", state], capture_output=True)
    base = next(iter(commands))
    print(f"{rounds} rounds, one of each command per round:")
    for name in commands:
        line = (f"  {name}: wall median {statistics.median(walls[name]):.1f} ms, least "
                f"{min(walls[name]):.1f}; CPU median {statistics.median(cpus[name]):.1f} ms,"
                f" least {min(cpus[name]):.1f}")
        if name != base:
            beyond = statistics.median(
                w - b for w, b in zip(walls[name], walls[base], strict=True))
            line += f"; beyond the interpreter {beyond:.1f} ms (median of the rounds)"
        print(line)
    for name, found in imports.items():
        print(f"  {name}, top-level imports of 2 ms or more under -X importtime: "
              + ", ".join(f"{module} {ms:.1f}" for ms, module in found))


if __name__ == "__main__":
    main()

"""README's commands, run as a newcomer runs them (real processes, a fresh home)."""

import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

from robox.sim.serve import HOST_QUIET_S

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def robox_cli(args: list[str], env: dict, check: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "robox.cli", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr, done.stderr
    if check:
        assert done.returncode == 0, done.stderr
    return done


def fresh_home(tmp_path) -> dict:
    return {**os.environ, "HOME": str(tmp_path / "home"), "XDG_DATA_HOME": "",
            "XDG_RUNTIME_DIR": str(tmp_path / "runtime"), "ROBOX_DEVICE": ""}


def test_the_main_command_prints_on_a_virtual_printer_that_stays_on(tmp_path):
    main = next(line.strip() for line in README.splitlines()
                if "pip install -q . &&" in line)
    words = shlex.split(main.split("&&")[-1])
    assert words[0] == ".venv/bin/robox-cli" and "--device" in words
    env = fresh_home(tmp_path)
    try:
        printed = robox_cli(words[1:], env)
        assert printed.stdout.startswith("sent example_")
        assert "errors: none" in printed.stdout
        state = tmp_path / "home" / ".local" / "share" / "robox" / "sim"
        assert (state / "sdcard.img").exists()
        # as the README says: still on afterwards, until `sim stop`
        shown = json.loads(robox_cli(["sim", "status", "--json"], env).stdout)
        assert shown["served"] and shown["state"] == str(state)
        listed = json.loads(robox_cli(["printers", "--json"], env, check=False).stdout or "[]")
        assert [p["device"] for p in listed if p["kind"] == "sim"] == [f"sim:{state}"]
    finally:
        stopped = robox_cli(["sim", "stop"], env)
    assert stopped.stdout.startswith("stopped the virtual printer")
    assert robox_cli(["sim", "status"], env, check=False).returncode == 3


def test_the_virtual_printer_section_runs_as_written(tmp_path):
    section = README[README.index("## The virtual printer"):]
    section = section[:section.index("\n## ")]
    commands = [line.strip().split("#")[0].split() for line in section.splitlines()
                if line.startswith("    robox-cli ")]
    names = [" ".join(c[1:4]) for c in commands]
    assert names[:2] == ["--device sim send-job", "--device sim status"], names
    env = fresh_home(tmp_path)
    job = tmp_path / "part.gcode"
    # 17 minutes of the printer's time (`simulate` says 1021 s). Running fast, the served
    # printer's clock gets ahead of a host slow to speak again by up to the 5 s for which
    # one error report keeps the host connected: on a loaded machine a job of a minute can
    # be over before the two commands' few dozen reports are. This one cannot.
    job.write_text("G28 X Y\n" + "".join(f"G1 X{10 + i % 40} Y{10 + i % 30} F120\n"
                                         for i in range(600)))
    try:
        began = time.monotonic()
        sent = robox_cli(["--device", "sim", "send-job", str(job), "--raw", "--json"], env)
        assert json.loads(sent.stdout)["printing"] is True
        status = robox_cli(["--device", "sim", "status", "--json"], env)
        if json.loads(status.stdout)["job"] != json.loads(sent.stdout)["id"]:
            # once the host has said nothing for HOST_QUIET_S of wall time (between its
            # last byte and the next command's first, on a machine that busy), the
            # printer takes it to have gone and runs on, to the job's end
            assert time.monotonic() - began > HOST_QUIET_S, status.stdout
        assert re.match(r"served on /dev/pts/\d+ by PID \d+",
                        robox_cli(["sim", "status"], env).stdout)
    finally:
        robox_cli(["sim", "stop"], env)

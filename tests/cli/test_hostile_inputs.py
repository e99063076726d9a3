"""Every command that reads a file, given what is not a file of its kind: a device that
never ends (/dev/zero), a FIFO nobody writes (opening it would block for ever), a
directory, and a 1 GiB sparse file. Each is refused at once with a one-line error and
a non-zero status, and the input is left as it was. An alarm turns a hang into a
failure, so a regression cannot stall the suite."""

import os
import signal

import pytest
from click.testing import CliRunner

from robox.cli import cli

COMMANDS = {
    "firmware verify": ["firmware", "verify", "@"],
    "firmware inject": ["firmware", "inject", "@"],
    "firmware to-sd": ["firmware", "to-sd", "@", "-o", "{tmp}/out.txt"],
    "firmware from-sd": ["firmware", "from-sd", "@", "-o", "{tmp}/out.bin"],
    "eeprom show": ["eeprom", "show", "@"],
    "eeprom fsck": ["eeprom", "fsck", "@"],
    "eeprom set": ["eeprom", "set", "@", "colour=1"],
    "sdcard ls": ["sdcard", "ls", "@"],
    "sdcard fsck": ["sdcard", "fsck", "@"],
    "sdcard get": ["sdcard", "get", "@", "X", "-o", "{tmp}/got"],
    "sdcard put (image)": ["sdcard", "put", "@", "{tmp}/job.gcode"],
    "sdcard put (file)": ["sdcard", "put", "{tmp}/card.img", "@"],
    "roboxise": ["roboxise", "@", "-o", "{tmp}/out.gcode"],
    "simulate": ["simulate", "@"],
    "send-job": ["--device", "sim-once:{tmp}/state", "send-job", "@"],
    "update-firmware": ["--device", "sim-once:{tmp}/state", "update-firmware", "@"],
}


@pytest.fixture
def inputs(tmp_path):
    (tmp_path / "job.gcode").write_bytes(b"G1 X1\n")
    assert CliRunner().invoke(cli, ["sdcard", "format", str(tmp_path / "card.img"),
                                    "--size", "1MiB"]).exit_code == 0
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "dir").mkdir()
    with open(tmp_path / "sparse", "wb") as f:
        f.truncate(1 << 30)
    return {"zero": "/dev/zero", "fifo": str(tmp_path / "fifo"),
            "directory": str(tmp_path / "dir"), "sparse": str(tmp_path / "sparse")}


def _alarm(*_args):
    raise TimeoutError("the command did not return: it blocked on its input")


@pytest.mark.parametrize("kind", ["zero", "fifo", "directory", "sparse"])
@pytest.mark.parametrize("name", list(COMMANDS))
def test_an_input_that_is_not_a_file_of_its_kind_is_refused_at_once(tmp_path, inputs,
                                                                       name, kind):
    path = inputs[kind]
    args = [a.replace("@", path).replace("{tmp}", str(tmp_path)) for a in COMMANDS[name]]
    before = os.stat(path)
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(20)
    try:
        result = CliRunner().invoke(cli, args)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert not isinstance(result.exception, TimeoutError), f"{name} blocked on {kind}"
    assert result.exit_code in (1, 2), (result.exit_code, result.output)
    if (name, kind) == ("sdcard fsck", "sparse"):  # a zeroed image: fsck's own verdict
        assert result.exit_code == 1 and "directory: capacity 0" in result.stdout
        return
    lines = [line for line in result.stderr.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("robox-cli: error: "), result.stderr
    assert "Traceback" not in result.output
    after = os.stat(path)
    assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)
    if kind == "sparse":  # still all holes: nothing was written into it
        assert after.st_blocks == before.st_blocks


@pytest.mark.parametrize("args", [
    ["sdcard", "put", "{tmp}/card.img", "{tmp}/job.gcode", "--id", ""],
    ["sdcard", "get", "{tmp}/card.img", ""],
    ["--device", "sim-once:{tmp}/state", "send-job", "{tmp}/job.gcode", "--id", ""],
    ["--device", "sim-once:{tmp}/state", "run-job", ""],
])
def test_an_empty_id_is_refused(tmp_path, inputs, args):
    """No command can name a file whose id is empty (0x94 with no id means the last
    job), so none is stored or asked for under one."""
    image = (tmp_path / "card.img").read_bytes()
    result = CliRunner().invoke(cli, [a.replace("{tmp}", str(tmp_path)) for a in args])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == \
        "robox-cli: error: file id is empty; a printer opens files by a non-empty id"
    assert (tmp_path / "card.img").read_bytes() == image
    assert not (tmp_path / "state").exists() or "run-job" in args

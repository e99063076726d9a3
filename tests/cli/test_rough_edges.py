"""What a new user trips over, each pinned: honest replies, --json, --yes, --timeout, -v,
quiet broken pipes and interrupts, a reel that extrudes, one default-id rule."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.cli.printer import describe_heater, describe_job
from robox.formats.eeprom import chip_image
from robox.host.client import Status
from robox.sim.printer import VirtualPrinter
from tests.cli.test_sdcard_cli import one_line_error
from tests.sim import serving

ROOT = Path(__file__).resolve().parents[2]


def run(*args, **kwargs):
    return CliRunner().invoke(cli, [str(a) for a in args], **kwargs)


@pytest.fixture
def served(tmp_path):
    with serving.served(tmp_path / "served") as path:
        yield f"serial:{path}"


# ------------------------------------------------------------ status text
def test_status_shows_a_heater_off_as_off_and_an_on_one_with_the_target_it_heats_to():
    virtual = VirtualPrinter()
    virtual.settle()

    def heaters():
        status = Status.parse(virtual.transact(b"\xb0"))
        return {name: describe_heater(t) for name, t in status.temperatures.items()}, status

    texts, status = heaters()
    assert texts == dict.fromkeys(("nozzle0", "nozzle1", "bed", "ambient"), "off")
    assert describe_job(status) == "job: none"
    for line in (b"M104 S200", b"M140 S60", b"M139 S45"):  # nozzle 0 target, bed first layer
        virtual.transact(b"\x95" + f"{len(line) + 1:04x}".encode() + line + b"\r")
    texts, _ = heaters()
    assert texts["nozzle0"] == "target 200.0"
    assert texts["nozzle1"] == "off"
    assert texts["bed"] == "first-layer target 45.0"  # M139 after M140: the mode it set


# ------------------------------------------------- pause, resume, abort
def test_pause_resume_and_abort_say_what_happened(served):
    def on(*args):
        return run("--device", served, *args)

    one_line_error(on("pause"), 1, "no job is printing")
    one_line_error(on("resume"), 1, "nothing to resume")
    assert on("abort").output == "no job was printing; heaters switched off\n"
    assert on("run-job", "spiral_vase").exit_code == 0
    paused = json.loads(on("pause", "--json").output)
    assert paused["job"] == "spiral_vase" and paused["state"] in ("pausing", "paused")
    assert not paused["was_paused"]
    assert on("pause").output.startswith("spiral_vase was already paused, at line ")
    assert on("resume").output.startswith("resumed spiral_vase at line ")
    assert on("resume").output.startswith("spiral_vase was not paused")
    aborted = json.loads(on("abort", "--json").output)
    assert aborted["aborted"] == "spiral_vase" and aborted["line"] >= 0
    assert json.loads(on("status", "--json").output)["job"] is None


# ------------------------------------------------------------- --json
def test_every_command_that_reports_answers_json(tmp_path, served):
    bin_file = tmp_path / "fw.bin"
    from robox.sim import images

    bin_file.write_bytes(images.firmware_image())
    dump = tmp_path / "reel.eeprom"
    commands = [
        ("--device", served, "gcode", "M105", "G90", "--json"),
        ("--device", served, "run-job", "spiral_vase", "--json"),
        ("--device", served, "pause", "--json"),
        ("--device", served, "resume", "--json"),
        ("--device", served, "abort", "--json"),
        ("--device", served, "write-eeprom", "reel0", "remaining_filament=99", "--json"),
        ("--device", served, "format-eeprom", "reel0", "--yes", "--json"),
        ("eeprom", "new", "reel", "-o", dump, "--json"),
        ("eeprom", "set", dump, "filament_diameter=2.85", "--json"),
        ("firmware", "to-sd", bin_file, "-o", tmp_path / "fw.txt", "--json"),
        ("firmware", "from-sd", tmp_path / "fw.txt", "-o", tmp_path / "back.bin", "--json"),
    ]
    answers = []
    for command in commands:
        result = run(*command)
        assert result.exit_code == 0, (command, result.output)
        answers.append(json.loads(result.stdout))
    assert [a["response"] for a in answers[0]][1] == ""
    assert answers[0][0]["response"].startswith("S:")
    assert answers[1] == {"printing": "spiral_vase"}
    assert answers[5] == {"eeprom": "reel0", "set": {"remaining_filament": "99"}}
    assert answers[8]["changed"] == ["filament_diameter"]
    assert (tmp_path / "back.bin").read_bytes() == bin_file.read_bytes()
    assert answers[10]["bytes"] == len(bin_file.read_bytes())


# --------------------------------------------------------------- --yes
def test_destroying_commands_ask_first_and_refuse_away_from_a_terminal(tmp_path):
    state = tmp_path / "printer"
    assert run("--device", f"sim-once:{state}", "status").exit_code == 0
    head = (state / "head.eeprom").read_bytes()
    one_line_error(run("--device", f"sim-once:{state}", "format-eeprom", "head"), 2, "--yes")
    assert (state / "head.eeprom").read_bytes() == head
    image = tmp_path / "card.img"
    assert run("sdcard", "format", image, "--size", "1MiB").exit_code == 0  # new: no question
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28\r")
    assert run("sdcard", "put", image, job, "--job").exit_code == 0
    before = image.read_bytes()
    one_line_error(run("sdcard", "format", image), 2, "--yes")
    assert image.read_bytes() == before
    refused = run("sdcard", "format", image, input="n\n")  # CliRunner's input is no tty
    assert refused.exit_code == 2 and image.read_bytes() == before
    assert run("sdcard", "format", image, "--yes").exit_code == 0
    assert json.loads(run("sdcard", "ls", image, "--json").output)["files"] == []


def test_a_no_at_the_question_changes_nothing(tmp_path, monkeypatch):
    image = tmp_path / "card.img"
    assert run("sdcard", "format", image, "--size", "1MiB").exit_code == 0
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28\r")
    assert run("sdcard", "put", image, job, "--job").exit_code == 0
    before = image.read_bytes()
    monkeypatch.setattr("robox.cli.common.at_terminal", lambda: True)
    result = run("sdcard", "format", image, input="n\n")
    assert result.exit_code == 1 and "not confirmed" in result.output
    assert image.read_bytes() == before
    result = run("sdcard", "format", image, input="y\n")
    assert result.exit_code == 0 and "reformatted" in result.output


# ------------------------------------------------------- -v and --timeout
def test_verbose_logs_the_wire(tmp_path):
    state = tmp_path / "printer"
    one = run("-v", "--device", f"sim-once:{state}", "status")
    assert "robox-cli: sent 0xb0 (1 bytes), got 0xe1 (222 bytes)" in one.stderr
    assert "  > b0" not in one.stderr
    two = run("-vv", "--device", f"sim-once:{state}", "status")
    assert "robox-cli:   > b0\n" in two.stderr
    assert "robox-cli:   < e1 " in two.stderr
    assert run("--device", f"sim-once:{state}", "status").stderr == ""


def test_timeout_bounds_the_wait_for_a_printer_that_does_not_answer():
    master, slave = os.openpty()  # a serial port with nothing behind it
    try:
        started = time.monotonic()
        result = run("--timeout", "0.3", "--device", f"serial:{os.ttyname(slave)}", "status")
        took = time.monotonic() - started
    finally:
        os.close(master)
        os.close(slave)
    assert result.exit_code == 1 and "did not answer" in result.output
    assert took < 5
    one_line_error(run("--timeout", "0", "status"), 2, "--timeout")


# ------------------------------------------------ pipes and interrupts
def test_a_closed_pipe_ends_quietly():
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run([sys.executable, "-m", "robox.cli", "sdcard", "ls",
                                 str(ROOT / "fixtures" / "sdcard.img")], stdout=write_end,
                                stderr=subprocess.PIPE, timeout=60)
    finally:
        os.close(write_end)
    assert result.returncode == 128 + signal.SIGPIPE  # as a Unix tool killed by SIGPIPE
    assert result.stderr == b""


def test_ctrl_c_while_starting_up_is_one_line_and_130(monkeypatch, capsys):
    from robox import launch

    class Interrupted:
        def __getattr__(self, name):
            raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "robox.cli", Interrupted())
    with pytest.raises(SystemExit) as stop:
        launch.main()
    assert stop.value.code == 130
    assert capsys.readouterr().err == "robox-cli: error: interrupted\n"


# ------------------------------------------------------- eeprom new
def test_a_new_reel_dump_extrudes(tmp_path):
    dump = tmp_path / "reel.eeprom"
    assert run("eeprom", "new", "reel", "-o", dump).exit_code == 0
    fields = json.loads(run("eeprom", "show", dump, "--kind", "reel", "--json").output)["fields"]
    assert float(fields["filament_multiplier"]["value"]) == 1.0
    assert float(fields["feed_rate_multiplier"]["value"]) == 1.0
    assert float(fields["filament_diameter"]["value"]) == 0.0
    assert dump.read_bytes() != chip_image(bytes(192))


# --------------------------------------------------------- one id rule
def test_send_job_and_sdcard_put_name_a_file_alike(tmp_path):
    job = tmp_path / "bracket v2.gcode"
    job.write_bytes(b"G28 X Y\rG1 X10 Y10 F3000\r")
    image = tmp_path / "card.img"
    assert run("sdcard", "format", image, "--size", "1MiB").exit_code == 0
    put = json.loads(run("sdcard", "put", image, job, "--job", "--json").output)
    sent = json.loads(run("--device", f"sim-once:{tmp_path / 'printer'}", "send-job", job, "--raw",
                          "--json").output)
    assert put["id"] == sent["id"]
    assert put["id"].startswith("bracket_")


def test_shell_completion_as_the_readme_says():
    env = {**os.environ, "COMP_WORDS": "robox-cli sdc", "COMP_CWORD": "1",
           "_ROBOX_CLI_COMPLETE": "bash_complete"}
    done = subprocess.run([sys.executable, "-m", "robox.cli"], env=env, capture_output=True,
                          timeout=60)
    assert done.stdout.decode().split() == ["plain,sdcard"]
    assert 'eval "$(_ROBOX_CLI_COMPLETE=bash_source robox-cli)"' in \
        (ROOT / "README.md").read_text()


# ------------------------------------------------ files: sizes, job flag, newest copy
def test_files_gives_what_this_computer_uploaded_and_marks_the_newest_copy(tmp_path):
    from robox.offline import sdcard as card_images

    state = tmp_path / "printer"
    device = ["--device", f"sim-once:{state}"]
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28 X Y\nG1 X20 Y20 F3000\nG1 X30 Y20\n")
    runner = CliRunner()
    for _ in range(2):
        sent = runner.invoke(cli, [*device, "send-job", str(job), "--json"])
        assert sent.exit_code == 0, sent.output
    name = json.loads(sent.stdout)["id"]
    listed = runner.invoke(cli, [*device, "files", "--json"])
    assert listed.exit_code == 0, listed.output
    files = json.loads(listed.stdout)
    copies = [f for f in files if f["id"] == name]
    stored = card_images.get_file(state / "sdcard.img", name)  # the card's own bytes
    assert [f["newest"] for f in copies] == [False, True]
    assert all(f["size"] == len(stored) and f["lines"] == stored.count(b"\r")
               and f["job"] is True and f["copies"] == 2 for f in copies)
    others = [f for f in files if f["id"] != name]
    assert others and all(f["size"] is None and f["job"] is None for f in others)
    text = runner.invoke(cli, [*device, "files"]).stdout.splitlines()
    assert text[0].split() == ["ID", "BYTES", "LINES", "KIND"]
    mine = [line for line in text if line.startswith(name)]
    assert mine[0].endswith("(older copy)") and mine[1].endswith("(newest copy)")
    assert f"{len(stored):,}" in mine[1] and " job " in mine[1]


# ------------------------------------------------------------ version
def test_version_names_the_firmware_models_build():
    """--version says whether the model runs compiled (robox.native), so a user can see
    what a plain `pip install .` gave them; the test suite's editable install is pure."""
    from robox.native import MODULES, compiled_modules, optimisation

    result = run("--version")
    assert result.exit_code == 0
    n = len(compiled_modules())
    how = f", {optimisation()}" if optimisation() else ""
    kind = "pure Python" if n == 0 else f"compiled core ({n} of {len(MODULES)} modules{how})"
    assert result.output == f"robox-cli, version 0.1.0; firmware model: {kind}\n"


def test_away_from_a_terminal_send_job_wait_says_how_far_it_got(tmp_path, monkeypatch):
    """A terminal shows bars; a log or a pipe gets a line a minute (here: every poll)."""
    from robox.cli import common

    monkeypatch.setattr(common, "PROGRESS_EVERY_S", 0.0)
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28 X Y\n" + b"G1 X20 Y20 F3000\nG1 X40 Y40\n" * 300)
    result = CliRunner().invoke(cli, ["--device", f"sim-once:{tmp_path / 'p'}", "send-job",
                                      str(job), "--raw", "--id", "part", "--wait"])
    assert result.exit_code == 0, result.output
    size = len(job.read_bytes())  # LF to CR: the same number of bytes
    uploads = [line for line in result.stderr.splitlines() if line.startswith("uploading")]
    prints = [line for line in result.stderr.splitlines() if line.startswith("printing")]
    assert uploads and uploads[-1].startswith("uploading part: ")
    assert uploads[-1].endswith(f" of {size} bytes (100%)")
    assert prints and all(line.startswith("printing part: ") and " of 601 lines (" in line
                          for line in prints)


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ctrl_c_or_kill_during_an_upload_says_what_it_left_and_resume_goes_on(tmp_path, sig):
    """SIGINT mid-upload to a served printer (paced, so the upload takes a few seconds):
    one line saying where it stopped and how to go on, status 130; --resume finishes it.
    A SIGTERM (`kill`) is taken the same way. The job's temporary copy is removed."""
    from tests.sim.serving import served

    state = tmp_path / "printer"
    job = tmp_path / "big.gcode"
    job.write_bytes(b"G28 X Y\n" + b"G4 P1\n" * 80_000)  # 480 KB: 7.5 s at 1x
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = {**os.environ, "ROBOX_DEVICE": "", "TMPDIR": str(temporary)}
    with served(state, speed=1) as pty:
        cli_ = [sys.executable, "-m", "robox.cli", "--device", f"serial:{pty}", "send-job",
                str(job), "--raw", "--id", "big"]
        # SIGINT's default action in the command, as a terminal's foreground job has it:
        # a child inherits an ignored SIGINT (the tests run as a background job of a
        # shell without job control, say), and Python then leaves it ignored
        sending = subprocess.Popen(cli_, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   env=env, preexec_fn=_sigint_default)
        time.sleep(2.5)  # started (even on a loaded machine), and well short of the end
        sending.send_signal(sig)
        _, err = sending.communicate(timeout=60)
        assert sending.returncode == 130, err.decode()
        assert not list(temporary.iterdir())
        line = err.decode().strip().splitlines()[-1]
        assert line.startswith("robox-cli: error: interrupted after ")
        assert line.endswith(f"of {len(job.read_bytes())} bytes of the upload; the printer "
                             "keeps it open, and prints what it holds if the job had begun: "
                             f"`robox-cli send-job {job} --resume` goes on from where it "
                             "stopped, `robox-cli abort` ends the job")
        resumed = subprocess.run([*cli_, "--resume", "--json"], capture_output=True,
                                 env=env, timeout=300)
        assert resumed.returncode == 0, resumed.stderr.decode()
        assert json.loads(resumed.stdout)["resumed_from_byte"] > 0

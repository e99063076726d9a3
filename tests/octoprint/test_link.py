"""The serial port OctoPrint sees for a Robox (octoprint_robox.link.RoboxLink), driven line
by line as OctoPrint drives it, against a served virtual printer through its pty."""

import hashlib
import io
import json
import os
import signal
import threading
import time

import pytest
from click.testing import CliRunner

from octoprint_robox import RoboxPlugin
from octoprint_robox.link import RoboxLink
from robox.cli import cli
from robox.host.devices import open_printer
from robox.locks import read_record
from robox.offline import sdcard as card_images

JOB = b"G28 X Y\r" + b"".join(b"G1 X%d Y%d F3000\r" % (10 + i % 50, 10 + (i * 7) % 50)
                             for i in range(900))


@pytest.fixture
def link(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "runtime"))
    state = tmp_path / "printer"
    with open_printer(f"sim:{state}") as printer:
        link = RoboxLink(printer, 0.2)
        link.state = state
        assert link.readline() == b"start\n"
        yield link
        link.close()
    record = read_record(state)
    if record:
        os.kill(record["pid"], signal.SIGKILL)


def say(link, line: str) -> list[str]:
    """Write one line as OctoPrint does (line number, checksum); its answer up to `ok`."""
    body = f"N7 {line}"
    checksum = 0
    for c in body.encode():
        checksum ^= c
    link.write(f"{body}*{checksum}\n".encode())
    answer = []
    while True:
        text = link.readline().decode()
        assert text, f"no ok for {line!r} (got {answer})"
        answer.append(text.rstrip("\n"))
        if text.startswith("ok"):
            return answer


def test_temperatures_under_octoprints_names_with_the_targets_heated_to(link):
    # a single-material head: one heater for both nozzles, so no tool 1
    assert say(link, "M105") == ["ok T0:20.0 /0.0 B:20.0 /0.0 C:20.0 /0.0"]
    assert say(link, "M104 S200") == ["ok"]
    assert say(link, "M140 S60") == ["ok"]
    deadline = time.monotonic() + 10  # the printer runs executed lines a moment later
    while " /60.0 C:" not in (answer := say(link, "M105")[-1]):
        assert time.monotonic() < deadline, answer
        time.sleep(0.05)
    assert " /200.0 B:" in answer and answer.startswith("ok T0:") and "T1:" not in answer
    assert " B:" in answer and answer.split(" B:")[1].split()[1] == "/60.0"
    status = link.printer.status()
    assert status.temperatures["nozzle0"]["target"] == 200.0
    say(link, "M104 S0")
    say(link, "M140 S0")


def test_firmware_and_card_as_octoprint_asks_for_them(link):
    m115 = say(link, "M115")
    assert m115[0].startswith(f"FIRMWARE_NAME:Robox {link.printer.revision()} UUID:")
    assert m115[0].endswith(" EXTRUDER_COUNT:1")  # a single-material head
    assert "Cap:SDCARD:1" in m115
    assert say(link, "M21") == ["SD card ok", "ok"]
    files = link.printer.files()
    listing = say(link, "M20")
    assert listing[0] == "Begin file list" and listing[-2:] == ["End file list", "ok"]
    assert [line.split()[0] for line in listing[1:-2]] == [f"{f}.gco"
                                                            for f in dict.fromkeys(files)]
    assert say(link, "M23 nothere") == ["open failed, File: nothere.", "ok"]


def test_an_upload_prints_while_it_uploads_and_octoprint_pauses_resumes_cancels(link):
    seen = {}

    def ready():
        # OctoPrint, told the file is stored, selects it by its path and prints it
        seen["select"] = say(link, "M23 /partA.gco")
        seen["print"] = say(link, "M24")
        seen["status"] = link.printer.status()
        seen["open"] = link.printer.send_file_report()  # the upload the printer has open
        seen["progress"] = say(link, "M27")

    link.upload(io.BytesIO(JOB), "partA", 901, ready=ready)
    size = len(JOB)  # OctoPrint shows a card file's size and "Printed" in bytes
    assert seen["select"] == [f"File opened: partA.gco Size: {size}", "File selected", "ok"]
    assert seen["status"].job == "partA" and seen["open"][0] == "partA"
    assert seen["progress"][0].startswith("SD printing byte ")
    done, total = map(int, seen["progress"][0].removeprefix("SD printing byte ").split("/"))
    assert total == size and 0 <= done <= size
    line = seen["status"].line  # the job's line (asked before), as the bytes it has run
    assert done >= (line - 1) * size // 901
    assert say(link, "M25") == ["ok"]
    deadline = time.monotonic() + 30
    while link.printer.status().pause != "paused":
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert say(link, "M24") == ["ok"]
    assert link.printer.status().pause not in ("pausing", "paused")
    # OctoPrint's cancel of a card print
    for line in ("M25", "M27", "M26 S0"):
        say(link, line)
    deadline = time.monotonic() + 30
    while link.printer.status().job is not None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert say(link, "M27") == ["Not SD printing", "ok"]
    assert f"partA.gco {size}" in say(link, "M20")
    assert say(link, "M23 partA.gco") == [f"File opened: partA.gco Size: {size}",
                                          "File selected", "ok"]
    link.close()
    state = link.state
    done = CliRunner().invoke(cli, ["sim", "stop", "--state", str(state), "--json"])
    assert json.loads(done.stdout)["stopped"] is True
    assert card_images.get_file(state / "sdcard.img", "partA") == JOB


def test_a_pause_from_octoprint_during_the_upload_is_not_undone_by_it(link):
    # the upload resumes a job paused where it caught up with the stored chunks; a pause
    # OctoPrint asked for (M25) at such a line looks the same and must stay
    lines = []

    def ready():
        say(link, "M23 partB.gco")
        say(link, "M24")
        deadline = time.monotonic() + 30
        while link.printer.status().pause != "paused":  # caught up with the two chunks
            assert time.monotonic() < deadline
            time.sleep(0.01)
        say(link, "M25")  # the user pauses it there
        lines.append(link.printer.status().line)

    link.upload(io.BytesIO(JOB * 2), "partB", 1802, ready=ready)
    status = link.printer.status()
    assert status.job == "partB" and status.pause == "paused" and status.line == lines[0]
    assert say(link, "M24") == ["ok"]  # OctoPrint's resume
    assert link.printer.status().pause not in ("pausing", "paused")
    link.printer.abort()


def test_octoprints_names_and_lines_for_the_robox():
    from octoprint_robox.link import card_id, robox_temperature_lines

    assert card_id("/partA.gco") == card_id("partA.GCO") == "partA"
    # Marlin's tool-indexed targets in the Robox's words (S: nozzle 0, T: nozzle 1)
    assert robox_temperature_lines("M104 T1 S210") == ["M104 T210"]
    assert robox_temperature_lines("M104 T0 S200") == ["M104 S200"]
    assert robox_temperature_lines("M104 S0") == ["M104 S0"]
    assert robox_temperature_lines("M109 T1 S215") == ["M104 T215", "M109"]
    assert robox_temperature_lines("M190 S60") == ["M140 S60", "M190"]
    assert robox_temperature_lines("M141 S35") == ["M170 S35"]
    assert robox_temperature_lines("M104 T1") is None  # the Robox's own: nozzle 1 on
    assert robox_temperature_lines("G1 X1") is None


def test_tool_one_target_reaches_nozzle_one_and_m114_parses(link):
    say(link, "M104 T1 S180")  # OctoPrint setting tool 1
    deadline = time.monotonic() + 10
    while link.printer.status().temperatures["nozzle1"].get("target") != 180.0:
        assert time.monotonic() < deadline, link.printer.status().temperatures
        time.sleep(0.05)
    assert link.printer.status().temperatures["nozzle0"].get("target") != 180.0
    say(link, "M104 T1 S0")
    comm = pytest.importorskip("octoprint.util.comm")
    position = say(link, "M114")
    assert comm.parse_position_line(position[0]) == {"x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0}


def test_a_file_of_unknown_size_reports_a_position_octoprint_does_not_cancel(link):
    short = b"G28 X Y\r" + b"G4 S5\r"
    link.printer.send_file(io.BytesIO(short), "other", run=True)  # another host's upload
    answer = say(link, "M27")[0]
    current, total = answer.removeprefix("SD printing byte ").split("/")
    assert int(current) > 0 and total == "0"  # OctoPrint's "0/0" means not printing
    link.printer.abort()


def test_a_job_started_from_octoprint_says_done_when_it_ends(link):
    short = b"G28 X Y\r" + b"G1 X20 Y20 F3000\r" * 3
    link.printer.send_file(io.BytesIO(short), "short", run=False)
    assert say(link, "M23 short")[-2:] == ["File selected", "ok"]
    assert say(link, "M24") == ["ok"]
    deadline = time.monotonic() + 60
    heard = []
    while "Done printing file" not in heard:
        assert time.monotonic() < deadline, heard
        heard += say(link, "M105")
        line = link.readline().decode().strip()
        if line:
            heard.append(line)


def test_the_plain_serial_report_gets_the_right_names():
    # OctoPrint's own reading of "S:19 @0 T:0 @0 B:20 ^0 A:20 *0": T is taken as the
    # current tool, S and A kept as they are
    parsed = {"T0": (0.0, None), "S": (19.0, None), "B": (20.0, None), "A": (21.0, None)}
    assert RoboxPlugin().temperatures(None, parsed) == {
        "T1": (0.0, None), "T0": (19.0, None), "B": (20.0, None), "C": (21.0, None)}
    marlin = {"T0": (200.0, 210.0), "B": (60.0, 60.0)}
    assert RoboxPlugin().temperatures(None, marlin) == marlin


def test_octoprints_card_upload_stores_the_job_under_send_jobs_id_and_prints_it(link, tmp_path):
    from robox.formats.sdcard import default_id

    plugin = RoboxPlugin()
    plugin._current = link
    source = tmp_path / "tower.gcode"
    source.write_bytes(JOB.replace(b"\r", b"\n"))
    said = []
    done = threading.Event()

    def succeeded(*args):
        said.append(("succeeded", *args[:2]))
        # as OctoPrint does when asked to print: select, then start
        say(link, f"M23 /{args[1]}")
        say(link, "M24")
        said.append(("printing", link.printer.status().job, link.printer.send_file_report()[0]))
        done.set()

    def failed(*args):
        said.append(("failed", *args[:2]))
        done.set()

    remote = plugin.card_upload(None, "tower.gcode", str(source),
                                lambda *args: said.append(("started", *args)), succeeded,
                                failed)
    expected = default_id("tower", hashlib.sha1(JOB).hexdigest())
    assert remote == f"{expected}.gco"
    assert done.wait(60)
    assert said == [("started", "tower.gcode", remote), ("succeeded", "tower.gcode", remote),
                    ("printing", expected, expected)]  # printing while it uploads
    deadline = time.monotonic() + 60
    while link.printer.send_file_report()[0] is not None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    link.printer.abort()
    link.close()
    CliRunner().invoke(cli, ["sim", "stop", "--state", str(link.state)])
    assert card_images.get_file(link.state / "sdcard.img", expected) == JOB


def test_a_job_printing_when_octoprint_connects_is_shown_and_followed(link):
    """OctoPrint takes a file selected with no M23 of its own, then a position past its
    start, for a print started at the printer (comm.py's external SD print)."""
    link.printer.send_file(io.BytesIO(JOB), "running", run=True)
    lines = JOB.count(b"\r")
    for _ in range(400):
        if link.printer.status().line > 0:
            break
        time.sleep(0.02)
    from robox.host import catalogue

    catalogue.record(link.printer.unique_id(), "running", len(JOB), lines, True, None)
    joining = RoboxLink(link.printer, 0.2)  # OctoPrint connecting while it prints
    assert joining.readline() == b"start\n"
    listed = say(joining, "M20")
    at = listed.index("End file list")
    opened, selected, position, ok = listed[at + 1:]
    assert opened == f"File opened: running.gco Size: {len(JOB)}"
    assert selected == "File selected"
    current, total = map(int, position.removeprefix("SD printing byte ").split("/"))
    assert 0 < current < total == len(JOB) and ok == "ok"
    assert say(joining, "M20")[-2:] == ["End file list", "ok"]  # told once
    joining.printer.abort()
    heard = []
    deadline = time.monotonic() + 60
    while "Done printing file" not in heard:  # followed to its end
        assert time.monotonic() < deadline, heard
        heard += say(joining, "M105")
        line = joining.readline().decode().strip()
        if line:
            heard.append(line)


def test_octoprint_on_a_robox_port_left_in_robox_mode_gets_it_back_in_text(
        tmp_path, monkeypatch):
    from tests.host.test_textmode import heard, into_robox_mode
    from tests.sim import serving

    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "runtime"))
    plugin = RoboxPlugin()
    with serving.served(tmp_path / "printer", speed=1) as pty:
        assert pty in plugin.port_names([])  # offered beside the robox: ports
        into_robox_mode(pty)
        assert heard(pty, b"M105\n") == b""  # deaf to OctoPrint's lines
        assert plugin.serial_factory(None, pty, 115200, 2.0) is None  # OctoPrint opens it
        assert heard(pty, b"M105\n").endswith(b"ok\r\n")
        assert plugin.serial_factory(None, "/dev/null", 115200, 2.0) is None  # not a Robox

        with open_printer(f"serial:{pty}") as printer:  # a job in Robox mode
            printer.send_file(io.BytesIO(JOB), "followed", run=True)
        link = plugin.serial_factory(None, pty, 115200, 0.2)
        try:
            assert isinstance(link, RoboxLink) and plugin._current is link
            told = [link.readline().decode().strip() for _ in range(2)]
            assert told[0] == "start"
            assert told[1].startswith("//action:notification Robox: job followed is under "
                                      "way in Robox mode")
            assert link.printer.status().pause == "running"
            assert "File opened: followed.gco Size: 0" in say(link, "M20")
            link.printer.abort()
        finally:
            link.close()


def test_a_paused_print_reports_the_position_octoprint_last_heard(link):
    """OctoPrint polls M27 while a card print is paused and takes a position past the
    one it last heard for a print restarted at the printer (it would leave Paused); a
    Robox finishes the line under way, and the link says the old position until the
    resume."""
    link.printer.send_file(io.BytesIO(JOB), "partC", run=False)
    say(link, "M23 partC.gco")
    say(link, "M24")
    deadline = time.monotonic() + 30
    while link.printer.status().line < 3:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    told = say(link, "M27")[0]
    while link.printer.status().line < int(told.split()[-1].split("/")[0]) + 3:
        assert time.monotonic() < deadline  # the printer moves on, unheard
        time.sleep(0.02)
    assert say(link, "M25") == ["ok"]
    assert link.printer.status().line > int(told.split()[-1].split("/")[0])
    assert say(link, "M27")[0] == told
    assert say(link, "M24") == ["ok"]
    resumed = say(link, "M27")[0]
    assert int(resumed.split()[-1].split("/")[0]) > int(told.split()[-1].split("/")[0])
    link.printer.abort()


def test_a_dual_material_head_shows_both_nozzle_heaters(link):
    link.printer.write_eeprom_fields("head", {"type_code": "RBX01-DM"})
    dual = RoboxLink(link.printer, 0.2)  # OctoPrint connecting to a dual-material head
    assert dual.readline() == b"start\n"
    assert say(dual, "M115")[0].endswith(" EXTRUDER_COUNT:2")
    answer = say(dual, "M105")[-1]
    assert answer.startswith("ok T0:") and " T1:" in answer and " B:" in answer


def test_a_job_the_printer_pauses_for_an_error_is_paused_for_octoprint(link):
    """An error that pauses a job (here nozzle 1's open thermistor, heated by a dual
    head's code on a single-material head): OctoPrint is told `//action:paused`, once,
    so it shows the print paused and offers Resume and Cancel."""
    bad = b"M104 T200\r" + b"G4 S2\r" * 30  # paused at the line after the error
    link.upload(io.BytesIO(bad), "badheat", 31)
    assert say(link, "M23 badheat.gco")[-1] == "ok"
    assert say(link, "M24") == ["ok"]
    heard: list[str] = []
    deadline = time.monotonic() + 60
    told = say(link, "M27")[0]
    while "//action:paused" not in heard:
        assert time.monotonic() < deadline, heard
        told = say(link, "M27")[0]
        heard += say(link, "M105")
    assert any("nozzle 1 thermistor" in line for line in heard)
    while link.printer.status().pause != "paused":
        assert time.monotonic() < deadline
        time.sleep(0.02)
    heard = say(link, "M105") + say(link, "M27")
    assert "//action:paused" not in heard  # told once
    assert told in heard  # the position OctoPrint last heard: a paused print stays put
    for line in ("M25", "M27", "M26 S0"):  # OctoPrint's Cancel
        say(link, line)
    assert link.printer.status().job is None


def test_a_cancel_heard_after_the_job_ended_leaves_the_next_print_unpaused(link):
    """OctoPrint's cancel (M25, M27, M26 S0) may reach a job that ends between its
    lines: the next print is then reported moving on, not held at the old position."""
    short = b"G28 X Y\r" + b"G4 P200\r"
    link.upload(io.BytesIO(short), "brief", 2)
    say(link, "M23 brief.gco")
    say(link, "M24")
    say(link, "M25")  # OctoPrint's cancel begins ...
    deadline = time.monotonic() + 60
    while link.printer.status().job is not None:  # ... the job ends on its own ...
        assert time.monotonic() < deadline
        if link.printer.status().pause == "paused":
            link.printer.resume()
        time.sleep(0.02)
    say(link, "M27")
    say(link, "M26 S0")  # ... and its end arrives
    slow = b"G28 X Y\r" + b"G1 X60 F60\rG1 X20 F60\r" * 100  # 40 s a line pair
    link.upload(io.BytesIO(slow), "next", 201)
    say(link, "M23 next.gco")
    say(link, "M24")
    first = int(say(link, "M27")[0].removeprefix("SD printing byte ").split("/")[0])
    while link.printer.status().line < 4:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    later = int(say(link, "M27")[0].removeprefix("SD printing byte ").split("/")[0])
    assert later > first
    link.printer.abort()

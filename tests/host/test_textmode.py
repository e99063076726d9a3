"""Handing a Robox to a text host and taking it from one (robox.host.textmode), on a
virtual printer served on a pseudo-terminal as a real one's /dev/ttyACM* appears.

The firmware's rules these pin (command.c): the first byte >= 0x80 where a command may
start puts the printer in Robox mode until a reset (0xfd); in Robox mode a byte < 0x80
is a BAD_COMMAND, and a latched BAD_COMMAND pauses a running job (is_error)."""

import contextlib
import time

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.formats.protocol import ErrorBit
from robox.host.client import Printer
from robox.host.textmode import (
    _await_text,
    answers_text,
    hand_to_text_host,
    is_robox_port,
    take_over,
)
from robox.host.transport import NoReply, SerialTransport
from robox.locks import InUse
from tests.sim import serving


@pytest.fixture
def pty(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "runtime"))
    with serving.served(tmp_path / "printer", speed=1) as path:
        yield path


def heard(path: str, data: bytes, seconds: float = 0.5) -> bytes:
    """Everything the printer says within `seconds` of `data`."""
    port = SerialTransport(path)
    try:
        port.write(data)
        out = b""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            with contextlib.suppress(NoReply):
                out += port.read(4096, 50)
        return out
    finally:
        port.close()


def into_robox_mode(path: str) -> None:
    port = SerialTransport(path)
    try:
        Printer(port).status()
    finally:
        port.close()


def test_an_idle_printer_in_robox_mode_is_reset_and_answers_text_again(pty):
    assert heard(pty, b"M105\n").endswith(b"ok\r\n")  # powered up in text mode
    into_robox_mode(pty)
    assert heard(pty, b"M105\n") == b""  # a text host gets nothing back now
    assert hand_to_text_host(pty) is None
    reply = heard(pty, b"M105\n")
    assert reply.startswith(b"S:") and reply.endswith(b"\r\nok\r\n")
    assert hand_to_text_host(pty) is None  # a printer in text mode: the same end


def test_a_printer_printing_in_robox_mode_is_left_printing_and_handed_back(pty, tmp_path):
    job = tmp_path / "long.gcode"
    job.write_text("G28 X Y\nG90\n" + "".join(f"G1 X{10 + i % 50} Y{10 + (i * 7) % 50} "
                                              "F3000\n" for i in range(3000)))
    sent = CliRunner().invoke(cli, ["--device", f"serial:{pty}", "send-job", str(job)])
    assert sent.exit_code == 0, sent.output
    printer = hand_to_text_host(pty)
    assert printer is not None
    try:
        status = printer.status()
        assert status.job is not None and status.pause == "running"
        assert printer.errors() == 0  # the question was a frame: no BAD_COMMAND, no pause
        line = status.line
        for _ in range(100):
            if printer.status().line > line:
                break
            time.sleep(0.05)
        assert printer.status().line > line and printer.status().pause == "running"
    finally:
        printer.abort()
        for _ in range(200):  # the abort's own moves (the head parks) end
            status = printer.status()
            if status.job is None and not status.busy:
                break
            time.sleep(0.05)
        printer.transport.close()
    assert hand_to_text_host(pty) is None  # idle now: handed over
    assert heard(pty, b"M105\n").endswith(b"ok\r\n")


def test_a_command_under_way_keeps_the_printer_in_robox_mode(pty):
    port = SerialTransport(pty)
    try:
        Printer(port).gcode("G4 S30\r")  # a 30 s dwell, queued and running
    finally:
        port.close()
    printer = hand_to_text_host(pty)
    assert printer is not None
    try:
        assert printer.status().busy and printer.status().job is None
    finally:
        printer.reset()
        printer.transport.close()


def test_a_line_a_text_host_left_unfinished_is_ended_before_the_frames(pty):
    port = SerialTransport(pty)
    port.write(b"M104 S12")  # a text host's line, cut short
    time.sleep(0.3)
    port.close()
    port = SerialTransport(pty)
    try:
        printer = take_over(port)
        # the line ran as the text host's next line end would have run it: the frame
        # that went with it (0xb3) was more text, "M104 S12\xb3" read as S12
        assert printer.status().temperatures["nozzle0"]["target"] == 12.0
        assert printer.errors() & (1 << ErrorBit.BAD_COMMAND) == 0
    finally:
        port.close()


def test_only_a_robox_port_is_taken_for_one(pty, tmp_path):
    assert is_robox_port(pty)
    assert not is_robox_port("/dev/null")
    assert not is_robox_port(str(tmp_path / "nothing"))
    assert not is_robox_port("")


def test_a_port_in_use_is_refused_with_who_holds_it(pty):
    holder = SerialTransport(pty)
    try:
        with pytest.raises(InUse, match=r"in use by"):
            hand_to_text_host(pty)
    finally:
        holder.close()


def test_a_printer_that_never_comes_back_after_its_reset_is_an_error(tmp_path):
    with pytest.raises(NoReply, match=r"has not answered in text within 1 s"):
        _await_text(str(tmp_path / "ttyACM9"), 1.0)


def test_answers_text_tells_the_modes_apart(pty):
    port = SerialTransport(pty)
    try:
        assert answers_text(port)
        Printer(port)
        assert not answers_text(port, 300)
    finally:
        port.close()

"""Handing a Robox to a text host (OctoPrint, Printrun), and taking it from one.

A Robox powers up in text (Pronterface) mode and goes over to Robox mode at the
first byte >= 0x80 that arrives where a command may start; only a reset (0xfd, or
switching it off) brings text mode back. No question tells a host which mode the
printer is in without a risk:

- a line sent to a printer in Robox mode is one BAD_COMMAND per byte, and a latched
  error pauses a running job (the firmware's `is_error` leaves BAD_COMMAND among
  the pausing errors);
- a frame sent to a printer in text mode puts it in Robox mode.

A frame is the safe question: what it changes, a reset undoes, and the reset is made
only when nothing would be lost by it. So `hand_to_text_host` asks for the status
with a frame. An idle printer is reset and awaited until it answers a line with
`ok`. A printer with a job on (printing or paused) or a command under way is left
as it is, in Robox mode, and handed back open: the caller drives it with frames
(OctoPrint's plugin follows the job through `octoprint_robox.link.RoboxLink`) and a
later connection, once it is idle, finds it ready for text.

Over USB a reset re-enumerates the printer: its /dev/ttyACM* goes away and comes
back a moment later, so the wait reopens the port until it answers.

`take_over` is the other direction: a printer a text host left in the middle of a
line takes a frame as more of that line; the line is ended and its answers drained
before the frames begin.
"""

from __future__ import annotations

import contextlib
import os
import time

from robox.host.client import DEFAULT_TIMEOUT_MS, Printer, ProtocolError
from robox.host.transport import (
    PRODUCT_ID,
    VENDOR_ID,
    NoReply,
    PermissionDenied,
    SerialTransport,
    TransportError,
)
from robox.locks import InUse

RESET_WAIT_S = 20.0  # a reset printer is back on USB within a few seconds
QUIET_MS = 300  # a text host's answers have drained once the line is this quiet
POLL_S = 0.2
FIRST_REPLY_MS = 2000  # a printer answers its first frame at once, unless mid-line


def _drain(transport) -> None:
    with contextlib.suppress(NoReply):
        while transport.read(256, QUIET_MS):
            pass


def take_over(transport, timeout_ms: int = DEFAULT_TIMEOUT_MS, idle=None) -> Printer:
    """A `Printer` on `transport`, also when a text host left the printer mid-line.

    The unfinished line is ended (the printer runs it, as it would at the text host's
    next line end) and its answers are drained; then the frames begin."""
    try:
        printer = Printer(transport, min(timeout_ms, FIRST_REPLY_MS), idle=idle)
    except (ProtocolError, NoReply):
        pass
    else:
        printer.timeout = timeout_ms
        return printer
    _answered(transport, b"\n", timeout_ms)  # the line's `ok`, after whatever it runs
    return Printer(transport, timeout_ms, idle=idle)


def is_robox_port(path: str) -> bool:
    """Whether the serial port `path` is a Robox: a served virtual printer's
    pseudo-terminal, or a USB serial port with the Robox's vendor and product ids."""
    if not path or not os.path.exists(path):
        return False
    real = os.path.realpath(path)
    from robox.sim.served import list_served

    if any(os.path.realpath(served["pty"]) == real for served in list_served()):
        return True
    try:
        from serial.tools import list_ports
    except ImportError:
        return False
    return any(port.vid == VENDOR_ID and port.pid == PRODUCT_ID
               and os.path.realpath(port.device) == real for port in list_ports.comports())


def answers_text(transport, timeout_ms: int = 1000) -> bool:
    """Whether the printer answers a blank line with `ok` (text mode). Only for a
    printer known to be idle or in text mode: in Robox mode the line end is a
    BAD_COMMAND."""
    return _answered(transport, b"\n", timeout_ms)


def _answered(transport, line: bytes, timeout_ms: int) -> bool:
    """Send `line`; whether its `ok` came within `timeout_ms` (the rest is drained)."""
    transport.write(line)
    heard = b""
    deadline = time.monotonic() + timeout_ms / 1000
    while b"ok" not in heard:
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        try:
            heard += transport.read(256, max(1, round(left * 1000)))
        except NoReply:
            return False
    _drain(transport)
    return True


def hand_to_text_host(path: str, timeout_ms: int = DEFAULT_TIMEOUT_MS,
                      wait_s: float = RESET_WAIT_S) -> Printer | None:
    """Leave the Robox on serial port `path` ready for a text host, or say why not.

    Returns None once the printer answers text (it was idle: it has been reset).
    Returns the open `Printer`, in Robox mode, when a job is on or a command is
    under way: a reset would end it, so the caller carries on with frames (and
    closes the printer's transport when done)."""
    transport = SerialTransport(path)
    keep = False
    try:
        printer = take_over(transport, timeout_ms)
        status = printer.status()
        if status.job is not None or status.busy:
            keep = True
            return printer
        printer.reset()
    finally:
        if not keep:
            transport.close()
    _await_text(path, wait_s)
    return None


def _await_text(path: str, wait_s: float) -> None:
    deadline = time.monotonic() + wait_s
    why = "it did not answer"
    while True:
        try:
            transport = SerialTransport(path)
        except (PermissionDenied, InUse):
            raise
        except TransportError as exc:  # gone from USB while it restarts
            why = str(exc)
        else:
            try:
                if answers_text(transport):
                    return
            except TransportError as exc:
                why = str(exc)
            finally:
                transport.close()
        if time.monotonic() >= deadline:
            raise NoReply(f"{path}: the Robox was reset to hand it to a text host, but it "
                          f"has not answered in text within {wait_s:.0f} s ({why})")
        time.sleep(POLL_S)

"""Raw protocol frames to and from a virtual printer, for tests (no host library).

The wire reads replies as a USB host does: as soon as they are sent, even while the
printer is inside a line that waits."""

from __future__ import annotations

import math

from robox.errors import RoboxError
from robox.formats.protocol import reply_length
from robox.sim.printer import VirtualPrinter


def ident(name: str | bytes) -> bytes:
    raw = name.encode() if isinstance(name, str) else name
    return raw.ljust(16, b"\0")


def hexn(value: int, digits: int) -> bytes:
    return f"{value:0{digits}x}".encode()


def float8(value: float) -> bytes:
    return f"{value:f}"[:8].encode().ljust(8, b" ")


class Wire:
    def __init__(self, printer: VirtualPrinter | None = None):
        self.printer = printer or VirtualPrinter()
        self.fw = self.printer.firmware
        self.usb = self.printer.usb

    def raw(self, data: bytes, timeout: float = 10.0) -> bytes:
        """Send bytes; read one complete report (Robox mode)."""
        try:
            out = self.printer.transact(data, timeout)
        except RoboxError as exc:
            raise AssertionError(str(exc)) from None
        assert len(out) == reply_length(out), out
        return out

    def line(self, text: bytes, timeout: float = 30.0) -> bytes:
        """A Pronterface line; the response up to and including ok."""
        self.usb.host_write(text)
        out = b""
        while not out.endswith(b"ok\r\n"):
            self.printer.run_until(lambda: self.usb.reply_waiting > 0, timeout)
            if not self.usb.reply_waiting:
                raise AssertionError(f"no ok for {text!r} (got {out!r})")
            out += self.usb.host_read(64)
        return out

    def ack(self, data: bytes) -> str:
        reply = self.raw(data)
        assert reply[0] == 0xE3 and len(reply) == 65, reply
        return reply[1:].decode()

    def ok(self, data: bytes) -> None:
        errors = self.ack(data)
        assert set(errors) == {"0"}, f"errors {errors} after {data[:4]!r}"

    def clear(self) -> None:
        self.ack(b"\xc0")

    def gcode(self, text: bytes) -> bytes:
        reply = self.raw(b"\x95" + hexn(len(text), 4) + text)
        assert reply[0] == 0xE7
        return reply[5:]

    def upload(self, file_id: str, data: bytes, job: bool = True, run_after: int | None = None,
               between=None) -> None:
        self.ok((b"\x97" if job else b"\x90") + ident(file_id))
        chunks = len(data) // 512
        for n in range(chunks):
            self.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
            if run_after is not None and n == run_after:
                self.ok(b"\x94" + ident(file_id))
            if between is not None:
                between(n)
        tail = data[chunks * 512 :]
        self.ok(b"\x92" + hexn(chunks, 8) + hexn(len(tail), 4) + tail)

    def wait_job_done(self, timeout: float = 20000.0) -> None:
        assert self.printer.run_until(lambda: not self.fw.job.running, timeout)


def job_text(lines: list[str]) -> bytes:
    return b"".join(line.encode() + b"\r" for line in lines)


def circle_job(count: int, heat: bool = True) -> bytes:
    lines = ["M140 S60", "M104 S210", "G28 X Y Z", "M190 S60", "M109 S210"] if heat else \
        ["G28 X Y Z"]
    lines.append("G90")
    for i in range(count):
        a = i * 0.1
        lines.append(f"G1 X{100 + 30 * math.cos(a):.3f} Y{75 + 30 * math.sin(a):.3f} E0.05 "
                     "F3000")
    lines += ["M104 S0", "M140 S0"]
    return job_text(lines)


# AutoMaker's maintenance macros, in shape (the job lines each sends); read by the
# motion tests and bench/motion.py, so kept here, apart from pytest
MACROS = {
    "home all": ["G28 X Y Z", "M114"],
    "level gantry": ["G28 X Y", "G0 X20 Y75", "G28 Z", "G0 X200 Y75", "G28 Z", "G38",
                     "G0 X113 Y75", "G28 Z"],
    "level bed": ["G28 X Y Z", "G39", "G0 X30 Y30", "G28 Z", "G0 X190 Y30", "G28 Z",
                  "G0 X110 Y130", "G28 Z", "G39 S0.2", "G1 X100 Y75 Z0.3 F6000"],
    "purge": ["M104 S210", "G28 X Y Z", "M109", "G0 X10 Y10 Z0.3", "T0", "G0 B1",
              "G1 X100 E20 F1200", "G1 B0 F150", "M104 S0"],
    "eject stuck material": ["M104 S210", "M109", "G36 E-40 F300", "M122 E", "M104 S0"],
    "tool changes": ["G28 X Y Z", "T0", "G0 X50 Y50 Z1", "G0 B1", "G1 X60 E2 F1200", "T1",
                     "G0 B1", "G1 X50 E2 F1200", "T0 X55 Y55", "G0 B0"],
}

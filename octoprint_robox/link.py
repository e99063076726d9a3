"""The serial port OctoPrint sees for a Robox driven in Robox mode.

OctoPrint speaks Marlin-style text to a serial port: G-code lines (with line
numbers and checksums), `ok`, `M105` temperatures, the SD commands M20-M27. A Robox
in Robox mode speaks framed commands (`robox.host.client.Printer`). `RoboxLink` is
the serial-like object OctoPrint reads and writes; it answers each line in text,
doing what the line asks through the client:

- `M105`: the status report's four heaters as `T0` (nozzle 0), `T1` (nozzle 1),
  `B` (bed) and `C` (ambient, OctoPrint's chamber), each with the target it is
  heating to now (0 when off).
- `M115`: the firmware's revision and unique ID, and the SD card capability.
- `M20`/`M21`/`M23`/`M24`/`M25`/`M26 S0`/`M27`: the printer's card. Files are listed
  by id; a file selected and started is run with 0x94, paused and resumed with
  0x98, cancelled (OctoPrint's M25, M27, M26 S0) with 0xff; `M27` reports the job's
  line against the lines the file has, when the link uploaded it (sizes are not
  on the wire). When the job ends, `Done printing file`.
- Any other line is executed by the printer (0x95) and answered with its reply.
- Errors the printer raises (0xb3, asked on every temperature poll, which also
  keeps the printer counting a host as connected) are said as
  `//action:notification Robox: ...` (OctoPrint shows them) and cleared.

A card upload (`RoboxLink.upload`) goes through the same client, a chunk at a
time between OctoPrint's own lines, and starts printing after the second chunk,
as `robox-cli send-job` does: print while uploading.
"""

from __future__ import annotations

import collections
import contextlib
import re
import threading
import time
from collections.abc import Callable

from robox.errors import RoboxError
from robox.formats.protocol import error_names

LINE_NUMBER = re.compile(r"^N-?\d+\s*")
CHECKSUM = re.compile(r"\*\d+\s*$")
MODES = {"1": "target", "2": "first_layer_target"}
SUFFIX = ".gco"  # OctoPrint prints only files with a G-code extension; card ids have none


def shown(file_id: str) -> str:
    return file_id + SUFFIX


def card_id(name: str) -> str:
    return name[: -len(SUFFIX)] if name.lower().endswith(SUFFIX) else name


def _target(heater: dict) -> float:
    which = MODES.get(heater.get("mode"))
    return float(heater.get(which) or 0.0) if which else 0.0


def temperature_line(status) -> str:
    t = status.temperatures
    parts = []
    for key, name in (("T0", "nozzle0"), ("T1", "nozzle1"), ("B", "bed"), ("C", "ambient")):
        parts.append(f"{key}:{t[name]['measured']:.1f} /{_target(t[name]):.1f}")
    return " ".join(parts)


class RoboxLink:
    """A serial-like object (readline, write, close, timeout) for OctoPrint."""

    def __init__(self, printer, read_timeout: float = 2.0,
                 closer: Callable[[], None] | None = None, port: str = "robox"):
        self.printer = printer
        self.port = port
        self.timeout = read_timeout
        self._closer = closer
        self._lock = threading.RLock()      # one exchange with the printer at a time
        self._output: collections.deque[str] = collections.deque(["start"])
        self._ready = threading.Condition()
        self._selected: str | None = None
        self._printing: str | None = None
        self._lines: dict[str, int] = {}    # file id -> lines, for files uploaded here
        self._closed = False
        exchange = printer.transact

        def one_at_a_time(frame: bytes) -> bytes:
            with self._lock:
                return exchange(frame)

        printer.transact = one_at_a_time  # an upload's chunks and OctoPrint's lines interleave

    # ------------------------------------------------------------ serial surface
    def write(self, data: bytes) -> int:
        text = data.decode("ascii", "replace")
        for line in text.replace("\r", "\n").split("\n"):
            line = CHECKSUM.sub("", LINE_NUMBER.sub("", line.strip())).strip()
            if line:
                self._say(*self._answer(line))
        return len(data)

    def readline(self) -> bytes:
        deadline = time.monotonic() + self.timeout
        with self._ready:
            while not self._output and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._ready.wait(min(left, 0.5))
                if not self._output:
                    self._watch_job()
            if self._output:
                return (self._output.popleft() + "\n").encode()
        return b""

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        self._closed = True
        with self._ready:
            self._ready.notify_all()
        if self._closer is not None:
            with self._lock:
                self._closer()
            self._closer = None

    # ----------------------------------------------------------------- answers
    def _say(self, *lines: str) -> None:
        with self._ready:
            self._output.extend(lines)
            self._ready.notify_all()

    def _answer(self, line: str) -> list[str]:
        word = line.split()[0].upper()
        try:
            with self._lock:
                handler = getattr(self, f"_{word}", None)
                if handler is not None:
                    return handler(line)
                reply = self.printer.gcode(line + "\r")  # a line runs once it has its end
        except RoboxError as exc:
            return [f"//action:notification Robox: {exc}", "ok"]
        return [*(r for r in reply.splitlines() if r.strip() and r.strip() != "ok"), "ok"]

    def _M105(self, line: str) -> list[str]:
        status = self.printer.status()
        notes = self._errors()
        return [*notes, f"ok {temperature_line(status)}"]

    def _M115(self, line: str) -> list[str]:
        return [f"FIRMWARE_NAME:Robox {self.printer.revision()} "
                f"UUID:{self.printer.unique_id()} EXTRUDER_COUNT:2",
                "Cap:SDCARD:1", "Cap:AUTOREPORT_TEMP:0", "ok"]

    def _M110(self, line: str) -> list[str]:
        return ["ok"]

    def _M21(self, line: str) -> list[str]:
        return ["SD card ok" if self.printer.sd_card_present() else "SD init fail", "ok"]

    def _M20(self, line: str) -> list[str]:
        names = list(dict.fromkeys(self.printer.files()))  # a repeated id is one file
        return ["Begin file list", *(f"{shown(n)} {self._lines.get(n, 0)}" for n in names),
                "End file list", "ok"]

    def _M23(self, line: str) -> list[str]:
        asked = line.split(None, 1)[1].strip() if " " in line else ""
        name = card_id(asked)
        if name not in self.printer.files():
            return [f"open failed, File: {asked}.", "ok"]
        self._selected = name
        return [f"File opened: {shown(name)} Size: {self._lines.get(name, 0)}",
                "File selected", "ok"]

    def _M24(self, line: str) -> list[str]:
        status = self.printer.status()
        if status.job is not None and status.pause in ("pausing", "paused", "selfie pause"):
            self.printer.resume()
        elif status.job is None and self._selected:
            self.printer.run_job(self._selected)
            self._printing = self._selected
        return ["ok"]

    def _M25(self, line: str) -> list[str]:
        if self.printer.status().job is not None:
            self.printer.pause()
        return ["ok"]

    def _M26(self, line: str) -> list[str]:
        if re.search(r"\bS0\b", line) and self.printer.status().job is not None:
            self.printer.abort()  # OctoPrint's cancel: M25, M27, M26 S0
            self._printing = None
        return ["ok"]

    def _M27(self, line: str) -> list[str]:
        status = self.printer.status()
        if status.job is None:
            return ["Not SD printing", "ok"]
        total = self._lines.get(status.job, 0)
        return [f"SD printing byte {min(status.line, total) if total else 0}/{total}", "ok"]

    # ------------------------------------------------------------- background
    def _errors(self) -> list[str]:
        bits = self.printer.errors()
        if not bits:
            return []
        self.printer.clear_errors()
        return [f"//action:notification Robox: {name}" for name in error_names(bits)]

    def _watch_job(self) -> None:
        """Say `Done printing file` once the job OctoPrint started has ended."""
        if self._printing is None or not self._lock.acquire(blocking=False):
            return
        try:
            with contextlib.suppress(RoboxError):
                if self.printer.status().job is None:
                    self._printing = None
                    self._output.append("Done printing file")
        finally:
            self._lock.release()

    # ----------------------------------------------------------------- upload
    def upload(self, source, file_id: str, lines: int, progress=None) -> None:
        """Store `source` on the card as job `file_id`, printing it while it uploads."""
        self._lines[file_id] = lines
        self._selected = file_id

        def each_chunk(done: int, total: int) -> None:
            if self._closed:
                raise RoboxError("the connection was closed during the upload")
            if progress is not None:
                progress(done, total)

        self._printing = file_id
        self.printer.send_file(source, file_id, progress=each_chunk)

"""The serial port OctoPrint sees for a Robox driven in Robox mode.

OctoPrint speaks Marlin-style text to a serial port: G-code lines (with line
numbers and checksums), `ok`, `M105` temperatures, the SD commands M20-M27. A Robox
in Robox mode speaks framed commands (`robox.host.client.Printer`). `RoboxLink` is
the serial-like object OctoPrint reads and writes; it answers each line in text,
doing what the line asks through the client:

- `M105`: the status report's heaters as `T0` (nozzle 0), `T1` (nozzle 1, only on a
  dual-material head: a single-material head has one heater for both nozzles), `B`
  (bed) and `C` (ambient, OctoPrint's chamber), each with the target it is heating to
  now (0 when off).
- `M115`: the firmware's revision and unique ID, the heads' extruder count, and the
  SD card capability.
- `M20`/`M21`/`M23`/`M24`/`M25`/`M26 S0`/`M27`: the printer's card. Files are listed
  by id; a file selected and started is run with 0x94, paused and resumed with
  0x98, cancelled (OctoPrint's M25, M27, M26 S0) with 0xff; `M27` reports the job's
  progress in bytes of the file (OctoPrint shows it as "Printed"): the job's line
  over the file's lines, scaled to the file's size, when this computer uploaded it
  (sizes are not on the wire). A job the printer paused for an error is told as
  `//action:paused`, so OctoPrint shows it paused and offers Resume and Cancel.
  When the job ends, `Done printing file`. A job found printing when OctoPrint
  connects (started by another host, or before a reconnection) is told
  after the card's list as a file selected and a position past its start, which
  OctoPrint takes for a print started at the printer: it shows and follows it.
- Any other line is executed by the printer (0x95) and answered with its reply.
- Errors the printer raises (0xb3, asked on every temperature poll, which also
  keeps the printer counting a host as connected) are said as
  `//action:notification Robox: ...` (OctoPrint shows them) and cleared.

A card upload (`RoboxLink.upload`) goes through the same client, a chunk at a
time between OctoPrint's own lines. Once two chunks are stored the upload counts
as done for OctoPrint, which then selects the file (M23) and, when asked to
print, starts it (M24) while the rest uploads: print while uploading, as
`robox-cli send-job` does. The upload resumes the job whenever it catches up
with it; a failure after that point is said as a notification. Sizes (lines)
come from the host's catalogue of what it uploaded (`robox.host.catalogue`).
"""

from __future__ import annotations

import collections
import contextlib
import re
import threading
import time
from collections.abc import Callable

from robox.errors import RoboxError
from robox.formats.heads import head_kind
from robox.formats.protocol import PAUSE_MASK_CONNECTED, error_names
from robox.host import catalogue

LINE_NUMBER = re.compile(r"^N-?\d+\s*")
CHECKSUM = re.compile(r"\*\d+\s*$")
MODES = {"1": "target", "2": "first_layer_target"}
SUFFIX = ".gco"  # OctoPrint prints only files with a G-code extension; card ids have none


def shown(file_id: str) -> str:
    return file_id + SUFFIX


def card_id(name: str) -> str:
    """The card id of a name OctoPrint uses (`/id.gco`: it selects a card's file by
    its path from the card's root)."""
    name = name.strip().lstrip("/")
    return name[: -len(SUFFIX)] if name.lower().endswith(SUFFIX) else name


def _target(heater: dict) -> float:
    which = MODES.get(heater.get("mode"))
    return float(heater.get(which) or 0.0) if which else 0.0


def temperature_line(status, nozzle_heaters: int = 2) -> str:
    """M105's reply: nozzle 1's heater only where the head has one."""
    t = status.temperatures
    parts = []
    for key, name in (("T0", "nozzle0"), ("T1", "nozzle1"), ("B", "bed"), ("C", "ambient")):
        if key == "T1" and nozzle_heaters < 2:
            continue
        parts.append(f"{key}:{t[name]['measured']:.1f} /{_target(t[name]):.1f}")
    return " ".join(parts)


def _word(text: str, letter: str) -> str | None:
    m = re.search(rf"(?<![A-Za-z]){letter}\s*(-?\d+(?:\.\d*)?|-?\.\d+)?", text,
                  re.IGNORECASE)
    if m is None:
        return None
    return m.group(1) or ""


def robox_temperature_lines(line: str) -> list[str] | None:
    """A Marlin-style temperature line as the Robox's own lines, or None if it is not one.

    Marlin's `M104 T1 S210` sets tool 1; the Robox reads `S` as nozzle 0's target and `T`
    as nozzle 1's, so it would set nozzle 0 to 210 and nozzle 1 to 1. `M109` and `M190`
    take no target on the Robox: the target is set first, then the wait. OctoPrint's
    chamber (`M141`/`M191`) is the Robox's ambient (`M170`)."""
    word = line.split()[0].upper() if line.split() else ""
    rest = line[len(word):]
    if word in ("M104", "M109"):
        tool, value = _word(rest, "T"), _word(rest, "S")
        if value is None:
            return None if tool is None or word == "M104" else ["M109"]
        letter = "T" if tool not in (None, "", "0") and float(tool) >= 1 else "S"
        lines = [f"M104 {letter}{value}"]
        return [*lines, "M109"] if word == "M109" else lines
    if word in ("M140", "M190"):
        value = _word(rest, "S")
        if value is None:
            return None
        return [f"M140 S{value}"] + (["M190"] if word == "M190" else [])
    if word in ("M141", "M191"):
        value = _word(rest, "S")
        return None if value is None else [f"M170 S{value}"]
    return None


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
        self._lines: dict[str, int] = {}    # file id -> lines, where known
        self._sizes: dict[str, int] = {}    # file id -> bytes, where known
        self._error_paused = False  # told OctoPrint the printer paused for an error
        self._head: tuple[str, int] | None = None  # (head EEPROM state, nozzle heaters)
        self._uploading: str | None = None  # the file this link is storing now
        self._held = False  # paused by OctoPrint: an upload's catch-up resume leaves it
        self._reported = 0  # the last position told to OctoPrint for the selected job
        with contextlib.suppress(RoboxError):
            known = catalogue.load(printer.unique_id())
            self._lines = {k: v["lines"] for k, v in known.items()
                           if isinstance(v.get("lines"), int)}
            self._sizes = {k: v["size"] for k, v in known.items()
                           if isinstance(v.get("size"), int)}
        self._closed = False
        self._announce: list[str] = []  # a job found printing, told after the card's list
        with contextlib.suppress(RoboxError):
            status = printer.status()
            if status.job is not None:
                self._printing = self._selected = status.job  # followed to its end
                self._announce = self._opened(status.job)
                if status.line > 0 and status.line != self._lines.get(status.job):
                    self._announce.append(self._position(status))
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
    def following(self) -> str | None:
        """The job this link follows to its end (found printing at connect, or started)."""
        return self._printing

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
                lines = robox_temperature_lines(line) or [line]
                reply = "".join(self.printer.gcode(one + "\r")  # runs once it has its end
                                for one in lines)
        except RoboxError as exc:
            return [f"//action:notification Robox: {exc}", "ok"]
        return [*(r for r in reply.splitlines() if r.strip() and r.strip() != "ok"), "ok"]

    def _M105(self, line: str) -> list[str]:
        status = self.printer.status()
        notes = self._errors(status)
        return [*notes, f"ok {temperature_line(status, self._nozzle_heaters(status))}"]

    def _nozzle_heaters(self, status) -> int:
        """The head's nozzle heaters: two on a dual-material head, one on the others;
        read from the head EEPROM again whenever its state changes (a head change)."""
        state = status.eeproms.get("head", "?")
        if self._head is None or self._head[0] != state:
            heaters = 2
            if state == "valid":
                with contextlib.suppress(RoboxError):
                    code = str(self.printer.read_eeprom_fields("head")["type_code"])
                    heaters = 2 if head_kind(code) == "dual" else 1
            self._head = (state, heaters)
        return self._head[1]

    def _M115(self, line: str) -> list[str]:
        heaters = self._nozzle_heaters(self.printer.status())
        return [f"FIRMWARE_NAME:Robox {self.printer.revision()} "
                f"UUID:{self.printer.unique_id()} EXTRUDER_COUNT:{heaters}",
                "Cap:SDCARD:1", "Cap:AUTOREPORT_TEMP:0", "ok"]

    def _M114(self, line: str) -> list[str]:
        """The Robox's position (`X: Y: Z: B: T:`), with the `E:` OctoPrint looks for
        (E is always relative on a Robox: its position is not kept)."""
        reply = self.printer.gcode("M114\r").strip()
        lines = [r for r in reply.splitlines() if r.strip() and r.strip() != "ok"]
        if lines and "E:" not in lines[0]:  # OctoPrint wants E straight after Z
            lines[0] = re.sub(r"(Z:\s*-?[\d.]+)", r"\1 E:0.000000", lines[0], count=1)
        return [*lines, "ok"]

    def _M110(self, line: str) -> list[str]:
        return ["ok"]

    def _M21(self, line: str) -> list[str]:
        return ["SD card ok" if self.printer.sd_card_present() else "SD init fail", "ok"]

    def _card_files(self) -> list[str]:
        """The card's ids, each once; the file being uploaded here too (the printer
        lists a file once it is whole, but a job prints while it uploads)."""
        names = list(dict.fromkeys(self.printer.files()))  # a repeated id is one file
        if self._uploading is not None and self._uploading not in names:
            names.append(self._uploading)
        return names

    def _M20(self, line: str) -> list[str]:
        names = self._card_files()
        # a job already printing when OctoPrint connected: told as a file selected (it
        # was, by someone) and a position past its start, which OctoPrint takes for a
        # print started at the printer, and follows
        announce, self._announce = self._announce, []
        return ["Begin file list", *(f"{shown(n)} {self._sizes.get(n, 0)}" for n in names),
                "End file list", *announce, "ok"]

    def _opened(self, name: str) -> list[str]:
        return [f"File opened: {shown(name)} Size: {self._sizes.get(name, 0)}",
                "File selected"]

    def _position(self, status) -> str:
        """`SD printing byte` for the job's line. While OctoPrint has it paused (or was
        told the printer paused it), the position it last heard: OctoPrint polls a
        paused card print and takes a position that has moved on for a print restarted
        at the printer, and a Robox finishes the moves under way before it stands
        still."""
        lines = self._lines.get(status.job, 0)
        size = self._sizes.get(status.job, 0)
        if lines and size:  # the job's line, as the bytes of the file it has run
            at = min(status.line, lines) * size // lines
        else:  # a size unknown is told as 0: a position with no percentage
            at, size = max(status.line, 1), 0
        if self._held or self._error_paused:
            at = self._reported
        self._reported = at
        return f"SD printing byte {at}/{size}"

    def _M23(self, line: str) -> list[str]:
        asked = line.split(None, 1)[1].strip() if " " in line else ""
        name = card_id(asked)
        if name not in self._card_files():
            return [f"open failed, File: {asked}.", "ok"]
        self._selected = name
        self._reported = 0
        return [*self._opened(name), "ok"]

    def _M24(self, line: str) -> list[str]:
        status = self.printer.status()
        if status.job is not None and status.pause in ("pausing", "paused", "selfie pause"):
            self._held = False
            self._error_paused = False
            self.printer.resume()
        elif status.job is None and self._selected:
            self.printer.run_job(self._selected)
            self._printing = self._selected
            self._reported = 0
            self._held = self._error_paused = False
        elif status.job is not None:
            self._printing = status.job  # already printing: followed to its end
        return ["ok"]

    def _M25(self, line: str) -> list[str]:
        if self.printer.status().job is not None:
            self._held = True
            self.printer.pause()
        return ["ok"]

    def _M26(self, line: str) -> list[str]:
        if re.search(r"\bS0\b", line):  # OctoPrint's cancel: M25, M27, M26 S0
            if self.printer.status().job is not None:
                self.printer.abort()
            self._printing = None  # (a job that ended meanwhile: cancelled all the same)
            self._held = False
            self._error_paused = False
        return ["ok"]

    def _M27(self, line: str) -> list[str]:
        status = self.printer.status()
        if status.job is None:
            return ["Not SD printing", "ok"]
        return [self._position(status), "ok"]

    # ------------------------------------------------------------- background
    def _errors(self, status) -> list[str]:
        """The printer's new errors as notifications (then cleared); an error that
        pauses a job, while one runs, also as `//action:paused`: the printer has paused
        it, and OctoPrint then shows it paused, with Resume and Cancel."""
        bits = self.printer.errors()
        if not bits:
            return []
        self.printer.clear_errors()
        notes = [f"//action:notification Robox: {name}" for name in error_names(bits)]
        if bits & PAUSE_MASK_CONNECTED and status.job is not None and not self._held \
                and not self._error_paused:
            self._error_paused = True
            notes.append("//action:paused")
        return notes

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
    def notify(self, message: str) -> None:
        """Say `message` as an OctoPrint notification."""
        self._say(f"//action:notification Robox: {message}")

    def upload(self, source, file_id: str, lines: int, progress=None, ready=None,
               sha1: str | None = None) -> None:
        """Store `source` on the card as job `file_id`. `ready` is called once it can
        print (more than one chunk stored): OctoPrint then selects and starts it while
        the rest uploads, and the upload resumes the job whenever it catches up."""
        self._lines[file_id] = lines
        size = source.seek(0, 2)
        self._sizes[file_id] = size

        def each_chunk(done: int, total: int) -> None:
            if self._closed:
                raise RoboxError("the connection was closed during the upload")
            if progress is not None:
                progress(done, total)

        self._uploading = file_id
        try:
            self.printer.send_file(source, file_id, run=False, follow=True,
                                   progress=each_chunk, ready=ready,
                                   held=lambda: self._held)
        finally:
            self._uploading = None
        with contextlib.suppress(RoboxError, OSError):
            catalogue.record(self.printer.unique_id(), file_id, size, lines, True, sha1)

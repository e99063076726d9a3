"""Persistent parameters (M500/M501/M502/M503) in flash, the unique ID, the hours counter.

Parameters live in flash pages 507 and 508: the 32-bit version (the running
image's anti-checksum, the word at 0xBC) and the parameters as the G-code
lines that set them. Parameters written by another build are ignored at boot:
defaults are used instead.
"""

from __future__ import annotations

import struct
from typing import ClassVar

from robox.firmware.cline import Line
from robox.formats import float8
from robox.formats.firmware import (
    DEFAULT_OFFSET,
    HOURS_PAGE,
    PAGE_SIZE,
    PARAMETER_PAGES,
    UNIQUE_ID_PAGE,
)

DEFAULTS = {
    "M92": {"X": 133.7, "Y": 133.7, "Z": 6400.0, "E": 747.0, "D": 747.0, "B": 2500.0},
    "M201": {"A": 1500.0},
    "M202": {"X": 200.0, "Y": 200.0, "Z": 3.5, "E": 35.0, "D": 35.0, "B": 6.0},
    "M906": {"X": 1.0, "Y": 1.0, "Z": 0.8, "E": 0.8, "D": 0.8, "B": 0.3},
    "M907": {"S": 0.2},
    "M908": {"S": 0.0},
    "M909": {"S": 0.0},
    "M510": {"S": 0.0},
    "M520": {"S": 0.0},
    "M526": {"S": 0.0},
    "M527": {"S": 0.0},
}
TITLES = {
    "M92": "Steps per mm", "M201": "Acceleration (mm/s^2)", "M202": "Maximum speeds (mm/s)",
    "M906": "Motor currents (A)", "M907": "Idle current fraction", "M908": "Parameter 908",
    "M909": "Parameter 909", "M510": "Parameter 510", "M520": "Parameter 520",
    "M526": "Parameter 526", "M527": "Parameter 527",
}
STORE = PARAMETER_PAGES[0] * PAGE_SIZE
STORE_SIZE = len(PARAMETER_PAGES) * PAGE_SIZE
HOURS_EVERY = 50  # hours-counter increments between flash writes


class Parameters:
    CODES: ClassVar[set[int]] = {int(code[1:]) for code in DEFAULTS}

    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.defaults()
        self.load()

    @property
    def version(self) -> int:
        return struct.unpack("<I", self.fw.hw.flash.read(DEFAULT_OFFSET, 4))[0]

    def defaults(self) -> None:
        self.values = {code: dict(words) for code, words in DEFAULTS.items()}

    def lines(self) -> list[str]:
        return [code + "".join(f" {k}{v:.2f}" for k, v in words.items())
                for code, words in self.values.items()]

    def save(self) -> None:
        text = ("\n".join(self.lines()) + "\n").encode("ascii")
        image = struct.pack("<I", self.version) + text
        image = image.ljust(STORE_SIZE, b"\xff")[:STORE_SIZE]
        flash = self.fw.hw.flash
        for i, page in enumerate(PARAMETER_PAGES):
            data = image[i * PAGE_SIZE : (i + 1) * PAGE_SIZE]
            if flash.page(page) != data:
                flash.write_page(page, data)

    def load(self) -> None:
        raw = self.fw.hw.flash.read(STORE, STORE_SIZE)
        if struct.unpack("<I", raw[:4])[0] != self.version:
            return  # another build's parameters (or none): keep what we have
        for text in raw[4:].split(b"\xff", 1)[0].split(b"\n"):
            line = Line(text)
            if line.has("M"):
                self.set_from_line(line.int("M"), line)

    def set_from_line(self, code: int, line: Line) -> None:
        """A parameter-setting M-code: each of its group's letters present is set."""
        group = self.values.get(f"M{code}")
        if group is None:
            return
        for key in group:
            if line.has(key):
                group[key] = line.float(key)

    def m503_text(self) -> bytes:
        out = [f"Ver: {self.version:08x}"]
        for code, line in zip(self.values, self.lines(), strict=True):
            out += [f"{TITLES[code]}:", line]
        return ("\r\n".join(out) + "\r\n").encode("ascii")

    # ------------------------------------------------------- unique ID
    def unique_id(self) -> bytes:
        return self.fw.hw.flash.page(UNIQUE_ID_PAGE)

    def write_unique_id(self, data: bytes) -> None:
        data = bytes(b & 0x7F for b in data[:PAGE_SIZE]).ljust(PAGE_SIZE, b"\0")
        if self.fw.hw.flash.page(UNIQUE_ID_PAGE) != data:
            self.fw.hw.flash.write_page(UNIQUE_ID_PAGE, data)

    # ----------------------------------------------------- hours counter
    def hours_text(self) -> bytes:
        return self.fw.hours.text()

    def write_hours(self, data: bytes) -> None:
        self.fw.hours.set_text(data)


class HoursCounter:
    """Printer hours in flash page 509 (8 ASCII characters); counts while a job runs.
    Also drives the 7.2 s filament and head-hours bookkeeping."""

    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        raw = self.fw.hw.flash.page(HOURS_PAGE)[:8]
        self.hours = float8.parse(raw) if raw != b"\xff" * 8 else 0.0
        self.next_tick = self.fw.clock.now + 7.2
        self.unsaved = 0

    def text(self) -> bytes:
        return float8.encode(self.hours)

    def set_text(self, data: bytes) -> None:
        self.hours = float8.parse(data)
        self._save()

    def _save(self) -> None:
        page = self.text().ljust(PAGE_SIZE, b"\xff")
        if self.fw.hw.flash.page(HOURS_PAGE) != page:
            self.fw.hw.flash.write_page(HOURS_PAGE, page)
        self.unsaved = 0

    def maintain(self) -> None:
        if self.fw.clock.now < self.next_tick:
            return
        self.next_tick += 7.2
        if self.fw.job.running:
            self.hours += 0.002
            self.unsaved += 1
            if self.unsaved >= HOURS_EVERY:
                self._save()

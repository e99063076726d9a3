"""Persistent parameters (M500/M501/M502/M503) in flash, the unique ID, the hours counter.

Parameters live in flash pages 507 and 508: the 32-bit version (the running
image's anti-checksum, the word at 0xBC) and the parameters as the G-code
lines that set them. Parameters written by another build are ignored at boot:
defaults are used instead.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, Final

from robox.firmware.carith import f32 as float32
from robox.firmware.carith import i64, to_uchar
from robox.firmware.cline import Line
from robox.formats import float8
from robox.formats.firmware import (
    DEFAULT_OFFSET,
    HOURS_PAGE,
    PAGE_SIZE,
    PARAMETER_PAGES,
    UNIQUE_ID_PAGE,
)
from robox.packed import vec

if TYPE_CHECKING:
    from robox.firmware.main import Firmware

AXES: Final = "XYZEDB"
STORE: Final = PARAMETER_PAGES[0] * PAGE_SIZE
STORE_SIZE: Final = len(PARAMETER_PAGES) * PAGE_SIZE


def amps_to_dac(amps: float) -> int:
    """A motor current in amps as the revision-2 drivers' 0..31 setting."""
    return max(0, min(31, to_uchar(float32(amps) * 32.0 * 0.13 / 0.325 - 0.5)))


def dac_to_amps(value: int) -> float:
    return float32((value + 1) * 0.325 / (32 * 0.13))


def _defaults() -> dict:
    """The firmware's factory settings (set_default_parameters, revision-2 Robox)."""
    f = float32
    return {
        "acceleration": 4, "allowable_error": 4,
        "steps_per_unit": dict(zip(AXES, map(f, (133.7, 133.7, 6400.0, 747.0, 747.0, 2500.0)),
                                   strict=True)),
        "max_speed": dict(zip(AXES, map(f, (200.0, 200.0, 3.5, 35.0, 35.0, 6.0)), strict=True)),
        "invert_direction": dict(zip(AXES, (1, 1, 1, 0, 0, 1), strict=True)),
        "invert_switch": dict(zip(AXES, (0, 0, 0, 1, 1, 0), strict=True)),
        "motor_current": dict(zip(AXES, (*map(amps_to_dac, (1.1, 1.1, 0.9, 1.3, 1.3)), 128),
                                  strict=True)),
        "reduced_current": {"X": 0, "Y": 0, "Z": 0, "E": amps_to_dac(0.7),
                            "D": amps_to_dac(0.7), "B": 0},
        "hold_current": dict(zip(AXES, (*map(amps_to_dac, (0.5, 0.5, 0.3, 0.5, 0.5)), 13),
                                 strict=True)),
        "filament_slip_threshold": f(10.0), "filament_until_slip_threshold": f(4.0),
        "home_distance": dict(zip(AXES, map(f, (-0.5, -0.5, -0.2, 350.0, 350.0, 0.0)),
                                  strict=True)),
        "travel": dict(zip(AXES, map(f, (226.0, 155.0, 100.2, 0.0, 0.0, 7.0)), strict=True)),
        "za_leadscrew_x": f(-37.546), "zb_leadscrew_x": f(251.5), "filament_load_x": f(190.0),
        "cover_unlock_y": f(161.5), "z_top_switch_min": f(79.0), "x_offset": 0.0,
        "y_offset": 0.0,
        "nozzle": {"P": f(0.08), "I": f(0.012), "D": f(0.55), "B": f(4380.0), "T": f(19193.0),
                   "U": 0, "prtd_a": f(-5.775e-7), "prtd_b": f(3.9083e-3), "prtd_tcal": 1.0},
        "bed": {"P": f(0.05), "I": f(0.006), "D": f(1.4), "B": f(3977.0), "T": f(62508.0),
                "U": 0},
        "ambient": {"P": f(0.1), "I": 0.0, "D": 0.0, "B": f(3977.0), "T": f(318790.0), "U": 0},
    }


_FACTORY: Final = _defaults()


class Parameters:
    """The firmware's parameters (`pa`): factory settings, the G-codes that change them,
    M500/M501/M502 and M503's text, byte for byte."""

    #: values["acceleration"], as a native integer for the step interrupt, which reads it
    #: at every run of interrupts (kept by changed())
    acceleration: i64
    #: The per-axis parameters read for every block or pass, in axis order (X Y Z E D B),
    #: kept by changed(): the numbers in packed vectors (compiled, read without unboxing:
    #: robox.packed), the switch levels in a list. Read them, never change them.
    steps_per_unit: vec[float]
    max_speed: vec[float]
    travel: vec[float]
    invert_switch: list[int]
    #: M909's slip thresholds (mm), as native floats for the pass that watches the wheels
    slip_threshold_mm: float
    until_slip_threshold_mm: float
    #: M533's Z (mm), as a native float for every queued move
    z_top_switch_min: float

    def __init__(self, firmware: Firmware):
        self.fw = firmware
        self.values: dict[str, Any] = {}
        self.acceleration = 0
        self.steps_per_unit = self.max_speed = self.travel = vec[float]([])
        self.invert_switch = []
        self.slip_threshold_mm = self.until_slip_threshold_mm = 0.0
        self.z_top_switch_min = 0.0

    def initialise(self) -> None:
        self.defaults()
        self.load()

    @property
    def version(self) -> int:
        return struct.unpack("<I", self.fw.hw.flash.read(DEFAULT_OFFSET, 4))[0]

    def defaults(self) -> None:
        """The factory settings (power-up, M502), in place: the motion and position
        objects hold this very dict, as the firmware's objects read its one `pa`."""
        self.values.clear()
        self.values.update({name: dict(value) if isinstance(value, dict) else value
                            for name, value in _FACTORY.items()})
        self.changed()

    def changed(self) -> None:
        """After `values` changed: what is kept from them made again (every change goes
        through set_from_line or defaults, or is M201 through Motion.set_acceleration)."""
        values = self.values
        self.acceleration = values["acceleration"]
        self.steps_per_unit = self._axis_floats("steps_per_unit")
        self.max_speed = self._axis_floats("max_speed")
        self.travel = self._axis_floats("travel")
        self.invert_switch = [int(values["invert_switch"][axis]) for axis in AXES]
        self.slip_threshold_mm = float(values["filament_slip_threshold"])
        self.until_slip_threshold_mm = float(values["filament_until_slip_threshold"])
        self.z_top_switch_min = float(values["z_top_switch_min"])

    def _axis_floats(self, name: str) -> vec[float]:
        values = self.values[name]
        return vec[float]([float(values[axis]) for axis in AXES])

    # ------------------------------------------------------------ G-codes
    def set_from_line(self, code: int, line: Line) -> None:
        """A parameter-setting M-code, as gcode.c handles each."""
        try:
            self._set_from_line(code, line)
        finally:
            self.changed()

    def _set_from_line(self, code: int, line: Line) -> None:
        v = self.values
        per_axis = {92: ("steps_per_unit", line.float), 202: ("max_speed", line.float),
                    510: ("invert_direction", line.bool), 520: ("travel", line.float),
                    526: ("invert_switch", line.bool), 527: ("home_distance", line.float)}
        if code in per_axis:
            name, read = per_axis[code]
            for axis in AXES:
                if line.has(axis):
                    v[name][axis] = int(read(axis)) if read == line.bool else read(axis)
        elif code == 201:
            if line.has("S"):
                v["acceleration"] = max(1, min(255, line.uint("S")))
            if line.has("T"):
                v["allowable_error"] = max(1, min(255, line.uint("T")))
        elif code in (301, 302, 303):
            group = v[{301: "nozzle", 302: "bed", 303: "ambient"}[code]]
            for letter in "PIDBT":
                if line.has(letter):
                    group[letter] = line.float(letter)
            if line.has("U"):
                group["U"] = int(line.bool("U"))
        elif code == 304:
            for letter, name in (("A", "prtd_a"), ("B", "prtd_b"), ("T", "prtd_tcal")):
                if line.has(letter):
                    v["nozzle"][name] = line.float(letter)
        elif code in (906, 907, 908):
            name = {906: "motor_current", 907: "hold_current", 908: "reduced_current"}[code]
            for axis in AXES if code != 908 else "ED":
                if line.has(axis):
                    v[name][axis] = amps_to_dac(line.float(axis))
        elif code == 909:
            if line.has("S"):
                v["filament_slip_threshold"] = line.float("S")
            if line.has("T"):
                v["filament_until_slip_threshold"] = line.float("T")
        elif code == 530:
            for letter, name in (("A", "za_leadscrew_x"), ("B", "zb_leadscrew_x")):
                if line.has(letter):
                    v[name] = line.float(letter)
        elif code in (531, 532, 533):
            letter, name = {531: ("X", "filament_load_x"), 532: ("Y", "cover_unlock_y"),
                            533: ("Z", "z_top_switch_min")}[code]
            if line.has(letter):
                v[name] = line.float(letter)
        elif code == 534:
            for letter, name in (("X", "x_offset"), ("Y", "y_offset")):
                if line.has(letter):
                    v[name] = line.float(letter)

    # ---------------------------------------------------------- M503 text
    def _groups(self) -> list[tuple[str, str]]:
        """Each group's title and the line that sets it, as show_parameters prints them."""
        v = self.values

        def f(x):
            return f"{float32(x):f}"

        def e(x):
            return f"{float32(x):e}"

        def axes(name, letters=AXES, fmt=f):
            return " ".join(f"{a}{fmt(v[name][a])}" for a in letters)

        def amps(name, letters=AXES):
            return " ".join(f"{a}{dac_to_amps(v[name][a]):f}" for a in letters)

        def tempcon(group):
            g = v[group]
            return (f"P{e(g['P'])} I{e(g['I'])} D{e(g['D'])} B{f(g['B'])} T{f(g['T'])} "
                    f"U{g['U']}")

        n = v["nozzle"]
        return [
            ("uSteps / Unit", f"M92 {axes('steps_per_unit')}"),
            ("Accel / allowable err", f"M201 S{v['acceleration']} T{v['allowable_error']}"),
            ("Max Speed (mm/s)", f"M202 {axes('max_speed')}"),
            ("Nozzle", f"M301 {tempcon('nozzle')}"),
            ("Bed", f"M302 {tempcon('bed')}"),
            ("Ambient", f"M303 {tempcon('ambient')}"),
            ("Nozzle PRTD", f"M304 A{e(n['prtd_a'])} B{e(n['prtd_b'])} T{e(n['prtd_tcal'])}"),
            ("Axis Invert", f"M510 {axes('invert_direction', fmt=str)}"),
            ("Axis Travel", f"M520 {axes('travel', 'XYZB')}"),
            ("Switch Invert", f"M526 {axes('invert_switch', fmt=str)}"),
            ("Home Dist", f"M527 {axes('home_distance', 'XYZED')}"),
            ("Z Leadscrew X Pos", f"M530 A{f(v['za_leadscrew_x'])} B{f(v['zb_leadscrew_x'])}"),
            ("Filament Load X Pos", f"M531 X{f(v['filament_load_x'])}"),
            ("Unlock Y Pos", f"M532 Y{f(v['cover_unlock_y'])}"),
            ("Z Top Sw Min Pos", f"M533 Z{f(v['z_top_switch_min'])}"),
            ("X/Y Offsets", f"M534 X{f(v['x_offset'])} Y{f(v['y_offset'])}"),
            ("Motor I (A)", f"M906 {amps('motor_current')}"),
            ("Hold I (A)", f"M907 {amps('hold_current')}"),
            ("Reduced I (A)", f"M908 {amps('reduced_current', 'ED')}"),
            ("Filament slip thr (mm)", f"M909 S{f(v['filament_slip_threshold'])} "
                                       f"T{f(v['filament_until_slip_threshold'])}"),
        ]

    def m503_text(self) -> bytes:
        """M503's response before its ok: 1275 bytes with the factory settings, which the
        firmware writes past its 1024-byte transmit buffer (the model sends the same bytes
        and overwrites nothing)."""
        text = f"Ver: {self.version & 0xFFFFFFFF:08x}\r\n"
        for title, setting in self._groups():
            text += f"{title}:\r\n  {setting}\r\n"
        return text.encode("ascii")

    # ----------------------------------------------------- M500 / M501
    def save(self) -> None:
        """M500: stored in flash pages 507-508 as the version word, then the M503 lines."""
        text = "".join(setting + "\n" for _, setting in self._groups()).encode("ascii")
        image = struct.pack("<I", self.version) + text
        image = image.ljust(STORE_SIZE, b"\xff")[:STORE_SIZE]
        flash = self.fw.hw.flash
        for i, page in enumerate(PARAMETER_PAGES):
            data = image[i * PAGE_SIZE : (i + 1) * PAGE_SIZE]
            if flash.page(page) != data:
                flash.write_page(page, data)

    def load(self) -> None:
        """M501 (and boot): parameters saved by this build, if any; otherwise unchanged."""
        raw = self.fw.hw.flash.read(STORE, STORE_SIZE)
        if struct.unpack("<I", raw[:4])[0] != self.version:
            return  # another build's parameters (or none)
        for text in raw[4:].split(b"\xff", 1)[0].split(b"\n"):
            line = Line(text)
            if line.has("M"):
                self.set_from_line(line.int("M"), line)

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
    """The printer's hours in flash page 509: the first 8 characters of "%f".

    Run time is counted in timer ticks while a job runs unpaused. Once no job runs
    and the motion queue is empty (writing flash stops interrupts), the page's own
    number plus the run time is written back in one page write, and the count starts
    again (maintain_hours_counter in parameters.c). A power cut during a job loses
    that job's time; one during the page write leaves whatever the page then holds."""

    def __init__(self, firmware: Firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.run_ticks = 0
        self.last_tick = self._tick()

    def _tick(self) -> int:
        return int(self.fw.clock.now * 1000 + 0.5)

    def _stored(self) -> bytes:
        return self.fw.hw.flash.page(HOURS_PAGE)[:8]

    def text(self) -> bytes:
        """0xb6: the page's 8 bytes, each masked to 7 bits."""
        return bytes(b & 0x7F for b in self._stored())

    def set_text(self, data: bytes) -> None:
        """0xc6: the 8 bytes as sent, and the run time so far forgotten."""
        self._program(bytes(data[:8]))
        self.run_ticks = 0

    def _program(self, data: bytes) -> None:
        # program_page: only when the first bytes differ; the rest of the page is zeroed
        if self._stored()[: len(data)] != data:
            self.fw.hw.flash.write_page(HOURS_PAGE, data.ljust(PAGE_SIZE, b"\0"))

    def due(self) -> bool:
        """A job's run time waits to be written (at the first pass with motion stopped)."""
        return self.run_ticks > 0 and not self.fw.job.running and self.fw.motion.empty()

    def maintain(self) -> None:
        now = self._tick()
        job = self.fw.job
        if job.running:
            if not job.paused():
                self.run_ticks = (self.run_ticks + now - self.last_tick) & 0xFFFFFFFF
        elif self.due():
            hours = float32(float8.parse(self._stored().split(b"\0", 1)[0])
                            + float32(self.run_ticks) / 3600000.0)
            self._program(f"{hours:f}        ".encode("ascii")[:8])
            self.run_ticks = 0
        self.last_tick = now

"""Position: coordinates, modes, volumetric extrusion, conversion to whole steps.

X/Y/Z/B are absolute (G90) or relative (G91); E and D are always relative and
in cubic millimetres of plastic, turned into filament length with the reel's
diameter and multiplier. Moves are split into segments of at most 2 mm of XYZ
travel; each is converted to whole microsteps per axis, the rounding residue
carried into the next, so thousands of tiny moves never drift. Every 7.2 s the
whole millimetres of filament used are taken off the reel's remaining length.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

from robox.firmware.gcode import Wait, wait_for
from robox.firmware.motion import Block
from robox.formats.eeprom import EepromIndex

SEGMENT_MM = 2.0
BOOKKEEPING_S = 7.2
HOMING_SPEED = {"X": 60.0, "Y": 60.0, "Z": 3.0, "B": 4.0}
EXTRUDERS = {"E": EepromIndex.REEL0, "D": EepromIndex.REEL1}
DEFAULT_DIAMETER = 1.75


class Position:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.logical = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}
        self.applied_offset = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}  # in the machine
        self.relative = False
        self.feed_rate = 3000.0  # mm/min
        self.tool = 0
        self.residue = dict.fromkeys("XYZEDB", 0.0)
        self.filament = {"E": [DEFAULT_DIAMETER, 1.0], "D": [DEFAULT_DIAMETER, 1.0]}
        self.feed_multiplier = {"E": 1.0, "D": 1.0}
        self.used_mm = {"E": 0.0, "D": 0.0}  # filament used since the last bookkeeping
        self.total_mm = {"E": 0.0, "D": 0.0}
        self.next_bookkeeping = self.fw.clock.now + BOOKKEEPING_S
        self.fw.eeproms.on_valid.append(self._eeprom_valid)

    # ------------------------------------------------------ reel settings
    def _eeprom_valid(self, index) -> None:
        if index in (EepromIndex.REEL0, EepromIndex.REEL1):
            self._load_reel("E" if index == EepromIndex.REEL0 else "D")

    def _load_reel(self, extruder: str) -> None:
        eeproms = self.fw.eeproms
        index = EXTRUDERS[extruder]
        if eeproms.status(index) != 2:
            return
        diameter = eeproms.get_float(index, "filament_diameter")
        multiplier = eeproms.get_float(index, "filament_multiplier")
        feed = eeproms.get_float(index, "feed_rate_multiplier")
        if diameter > 0:
            self.filament[extruder] = [diameter, multiplier if multiplier > 0 else 1.0]
        if feed > 0:
            self.feed_multiplier[extruder] = feed

    def reload_reels(self) -> None:
        for extruder in "ED":
            self._load_reel(extruder)

    def set_filament_info(self, extruder: str, diameter: float, multiplier: float) -> None:
        self.filament[extruder] = [diameter, multiplier]

    def set_feed_rate_multiplier(self, extruder: str, value: float) -> None:
        self.feed_multiplier[extruder] = value

    def extruder_present(self, extruder: str) -> bool:
        if extruder == "E":
            return True
        head = self.fw.eeproms
        return head.status(EepromIndex.HEAD) == 2 and \
            head.states[EepromIndex.HEAD].data[:16].rstrip(b"\0 ").endswith(b"DM")

    # --------------------------------------------------------- reporting
    def steps_per_mm(self, axis: str) -> float:
        return self.fw.parameters.values["M92"][axis]

    def machine_mm(self, axis: str) -> float:
        """Where the axis is, with the sub-step residue carried for the next move added
        back (so an idle axis reports exactly the position it was sent to)."""
        steps = self.fw.hw.machine.axes[axis].position
        if self.fw.motion.idle():
            steps += self.residue[axis]
        return steps / self.steps_per_mm(axis)

    def reported_position(self, axis: str) -> float:
        return self.machine_mm(axis) - self._offset(axis)

    def _offset(self, axis: str) -> float:
        if axis not in "XYZB":
            return 0.0
        eeproms = self.fw.eeproms
        if eeproms.status(EepromIndex.HEAD) != 2:
            return 0.0
        return eeproms.get_float(EepromIndex.HEAD, f"nozzle{self.tool}_{axis.lower()}_offset")

    def m114_text(self) -> bytes:
        x, y, z = (self.reported_position(a) for a in "XYZ")
        b = self.reported_position("B") * (-1 if self.tool == 1 else 1)
        return f"X:{x:f} Y:{y:f} Z:{z:f} B:{b:f} T:{self.tool}\r\n".encode()

    def m119_text(self) -> bytes:
        m = self.fw.hw.machine
        a = m.axes
        flags = [a["X"].switch, a["Y"].switch, a["Z"].switch, m.z_top_switch, m.filament_e,
                 m.filament_d, a["B"].switch, m.filament_e, m.filament_d]
        x, y, z, zt, e, d, b, ei, di = (int(f) for f in flags)
        return (f"M119 X:{x} Y:{y} Z:{z} Z+:{zt} E:{e} D:{d} B:{b} Eindex:{ei} "
                f"Dindex:{di}\r\n").encode()

    def filament_report(self) -> list[float]:
        (ed, em), (dd, dm) = self.filament["E"], self.filament["D"]
        return [ed, em, dd, dm, self.feed_multiplier["D"], self.feed_multiplier["E"]]

    # ------------------------------------------------------------- moves
    def select_tool(self, tool: int) -> Iterator[Wait]:
        if tool in (0, 1):
            yield from wait_for(self.fw.motion.idle, Wait(motion=True))
            self.tool = tool

    def set_position(self, p: dict) -> None:
        for axis in "XYZB":
            if axis in p:
                self.logical[axis] = p[axis]

    def filament_mm(self, extruder: str, volume: float) -> float:
        diameter, multiplier = self.filament[extruder]
        return volume * multiplier / (math.pi * diameter * diameter / 4.0)

    def move(self, p: dict, speed_limit: float | None = None) -> Iterator[Wait]:
        if "F" in p and p["F"] > 0:
            self.feed_rate = p["F"]
        target = dict(self.logical)
        for axis in "XYZB":
            if axis in p:
                target[axis] = target[axis] + p[axis] if self.relative else p[axis]
        extrude = {e: self.filament_mm(e, p[e]) for e in "ED" if e in p}
        # the machine goes to the logical target plus the current tool's offset
        offset = {a: self._offset(a) for a in "XYZB"}
        delta = {a: target[a] + offset[a] - self.logical[a] - self.applied_offset[a]
                 for a in "XYZB"}
        self.applied_offset = offset
        travel = math.sqrt(delta["X"] ** 2 + delta["Y"] ** 2 + delta["Z"] ** 2)
        segments = max(1, math.ceil(travel / SEGMENT_MM - 1e-9))
        speed = self.feed_rate / 60.0
        if extrude:
            extruder = "D" if "D" in extrude and "E" not in extrude else "E"
            speed *= self.feed_multiplier[extruder]
        if speed_limit is not None:
            speed = min(speed, speed_limit)
        for _ in range(segments):
            part = {a: delta[a] / segments for a in "XYZB"}
            part.update({e: mm / segments for e, mm in extrude.items()})
            yield from self._segment(part, speed)
        self.logical = target

    def _segment(self, part: dict[str, float], speed: float) -> Iterator[Wait]:
        steps = {}
        for axis, mm in part.items():
            exact = mm * self.steps_per_mm(axis) + self.residue[axis]
            whole = round(exact)
            self.residue[axis] = exact - whole
            if whole:
                steps[axis] = whole
        if not steps:
            return  # shorter than a step: absorbed into the next move
        xyz = [steps.get(a, 0) / self.steps_per_mm(a) for a in "XYZ"]
        length = math.sqrt(sum(v * v for v in xyz))
        if length > 0:
            direction = tuple(v / length for v in xyz)
        else:
            length = max(abs(steps.get(a, 0)) / self.steps_per_mm(a) for a in "EDB")
            direction = (0.0, 0.0, 0.0)
        limits = self.fw.parameters.values["M202"]
        for axis, count in steps.items():
            axis_mm = abs(count) / self.steps_per_mm(axis)
            if axis_mm > 0 and length > 0:
                speed = min(speed, limits[axis] * length / axis_mm)
        motion = self.fw.motion
        yield from wait_for(motion.room, Wait(motion=True))
        motion.add(Block(steps, length, max(speed, 0.1), direction))

    def home(self, axes: list[str]) -> Iterator[Wait]:
        """Each axis runs towards its switch until it closes (the move ends there)."""
        motion = self.fw.motion
        yield from wait_for(motion.idle, Wait(motion=True))
        for axis in axes:
            hw_axis = self.fw.hw.machine.axes[axis]
            distance = max(0, hw_axis.position) / self.steps_per_mm(axis)
            motion.add(Block({}, distance, HOMING_SPEED[axis], homing=axis))
            yield from wait_for(motion.idle, Wait(motion=True))
            self.logical[axis] = 0.0
            self.residue[axis] = 0.0
            self.applied_offset[axis] = 0.0

    def completed(self, block: Block) -> None:
        for extruder in "ED":
            if extruder in block.steps:
                mm = block.steps[extruder] / self.steps_per_mm(extruder)
                self.used_mm[extruder] += mm
                self.total_mm[extruder] += mm

    # ----------------------------------------------------- pause parking
    def save_state(self) -> dict:
        return {"logical": dict(self.logical), "feed_rate": self.feed_rate,
                "relative": self.relative, "tool": self.tool}

    def park(self, where: dict, lift: float) -> Iterator[Wait]:
        relative, feed = self.relative, self.feed_rate
        self.relative = False
        z = min(self.logical["Z"] + lift, 100.0)
        yield from self.move({"Z": z, "F": 600.0})
        yield from self.move({"X": where["X"], "Y": where["Y"], "F": 6000.0})
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        self.relative, self.feed_rate = relative, feed

    def restore_state(self, state: dict) -> Iterator[Wait]:
        self.relative = False
        saved = state["logical"]
        yield from self.move({"X": saved["X"], "Y": saved["Y"], "F": 6000.0})
        yield from self.move({"Z": saved["Z"], "F": 600.0})
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        self.logical = dict(saved)
        self.feed_rate, self.relative, self.tool = (state["feed_rate"], state["relative"],
                                                    state["tool"])

    # ------------------------------------------------------- bookkeeping
    def bookkeeping(self) -> None:
        """Every 7.2 s (the hours counter calls it): filament and head hours to the EEPROMs."""
        now = self.fw.clock.now
        if now < self.next_bookkeeping:
            return
        self.next_bookkeeping = now + BOOKKEEPING_S
        eeproms = self.fw.eeproms
        for extruder, index in EXTRUDERS.items():
            whole = math.trunc(self.used_mm[extruder])
            if whole and eeproms.status(index) == 2:
                remaining = eeproms.get_float(index, "remaining_filament")
                eeproms.set_float(index, "remaining_filament", remaining - whole)
                self.used_mm[extruder] -= whole
        if self.fw.heaters.head_hot() and eeproms.status(EepromIndex.HEAD) == 2:
            hours = eeproms.get_float(EepromIndex.HEAD, "head_hours")
            eeproms.set_float(EepromIndex.HEAD, "head_hours", hours + 0.002)

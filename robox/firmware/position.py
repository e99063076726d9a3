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

from robox.firmware.cline import Line, float32, report_float, strtof
from robox.firmware.gcode import Wait, wait_for
from robox.firmware.motion import Block
from robox.formats.eeprom import EepromIndex

SEGMENT_MM = 2.0
PARKING_Z = 2.0
TRAVEL = {"X": 226.0, "Y": 155.0, "Z": 100.2}
HOMING_SPEED = {"X": 60.0, "Y": 60.0, "Z": 3.0, "B": 4.0}
EXTRUDERS = {"E": EepromIndex.REEL0, "D": EepromIndex.REEL1}
DEFAULT_DIAMETER = 1.75


class Position:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        # the firmware's bookkeeping: where moves should go (tool-relative) and where the
        # machine will be once the queued moves are done, in mm (B: valve units)
        self.logical = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}
        self.position = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}
        self.tool_offset = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}
        self.relative = False
        self.homed: set[str] = set()  # axes homed or set by G92 (B: a tool selected)
        self.home_delta = dict.fromkeys("XYZEDB", 0.0)
        self.levelling_points = 0
        self.z_washout = 0.0
        self.unpark_state: dict | None = None
        self.feed_rate = 600.0  # mm/min (the firmware's 10 mm/s)
        self.tool = 0
        self.e_residue = {"E": 0.0, "D": 0.0}  # queued E/D not yet whole steps
        self.filament = {"E": [DEFAULT_DIAMETER, 1.0], "D": [DEFAULT_DIAMETER, 1.0]}
        self.feed_multiplier = {"E": 1.0, "D": 1.0}
        self.total_mm = {"E": 0.0, "D": 0.0}
        # filament queued since the last bookkeeping, in mm (float, as the firmware keeps it)
        self.e_destination = {"E": 0.0, "D": 0.0}

    # ------------------------------------------------------ reel settings
    def filament_info_from_reel(self) -> None:
        """Diameter, multiplier and feed-rate multiplier of each extruder from its reel;
        a value stays as it is when that reel is not VALID."""
        eeproms = self.fw.eeproms
        for extruder, index in EXTRUDERS.items():
            diameter, multiplier = self.filament[extruder]
            self.filament[extruder] = [eeproms.float_at(index, 0x50, diameter),
                                       eeproms.float_at(index, 0x58, multiplier)]
        for extruder, index in EXTRUDERS.items():
            self.feed_multiplier[extruder] = eeproms.float_at(index, 0x60,
                                                              self.feed_multiplier[extruder])


    def update_reel_filament_length(self) -> None:
        """Every 7.2 s: whole millimetres queued since the last time come off each reel's
        remaining length (the reel's field is rewritten even when nothing was used)."""
        eeproms = self.fw.eeproms
        for extruder, index in EXTRUDERS.items():
            used = math.floor(self.e_destination[extruder])
            eeproms.write_float_at(index, 0xB8,
                                   float32(eeproms.float_at(index, 0xB8, 0.0) - used))
            self.e_destination[extruder] = float32(self.e_destination[extruder] - used)

    def extruder_present(self, extruder: str) -> bool:
        if extruder == "E":
            return True
        head = self.fw.eeproms
        return head.status(EepromIndex.HEAD) == 2 and \
            head.states[EepromIndex.HEAD].data[:16].rstrip(b"\0 ").endswith(b"DM")

    # --------------------------------------------------------- reporting
    def steps_per_mm(self, axis: str) -> float:
        return self.fw.parameters.values["steps_per_unit"][axis]

    def reported_position(self, axis: str) -> float:
        """Where the head will be once queued moves are done, less the tool offset."""
        return float32(self.position[axis] - self.tool_offset[axis])

    def _eeprom_offset(self, tool: int, axis: str) -> float:
        """Tool `tool`'s offset from the head EEPROM (tools 0 and 1; none for others)."""
        if tool >= 2:
            return 0.0
        address = 0x40 + 0x30 * tool + 8 * "XYZB".index(axis)
        return self.fw.eeproms.float_at(EepromIndex.HEAD, address, 0.0)

    def m114_text(self) -> bytes:
        x, y, z = (self.reported_position(a) for a in "XYZ")
        b = self.reported_position("B") * (-1 if self.tool == 1 else 1)
        return f"X:{x:f} Y:{y:f} Z:{z:f} B:{b:f} T:{self.tool}\r\n".encode()

    def _switches(self) -> dict[str, int]:
        """Each switch as the firmware reads it (input XOR its invert setting)."""
        m = self.fw.hw.machine
        a = m.axes
        return {"X": a["X"].switch, "Y": a["Y"].switch, "Z": a["Z"].switch,
                "E": m.filament_e, "D": m.filament_d, "B": a["B"].switch}

    def m119_text(self) -> bytes:
        m = self.fw.hw.machine
        s = {k: int(bool(v)) for k, v in self._switches().items()}
        return (f"M119 X:{s['X']} Y:{s['Y']} Z:{s['Z']} Z+:{int(m.z_top_switch)} "
                f"E:{s['E']} D:{s['D']} B:{s['B']} Eindex:{int(m.index_e)} "
                f"Dindex:{int(m.index_d)}\r\n").encode()

    def switch_flags(self) -> bytes:
        """Status bytes 27..33: X, Y, Z, E, D, B switches and the lid."""
        flags = [*self._switches().values(), self.fw.hw.machine.lid_closed]
        return bytes(0x31 if f else 0x30 for f in flags)

    def index_and_z_top_flags(self) -> bytes:
        m = self.fw.hw.machine
        return bytes(0x31 if f else 0x30 for f in (m.index_e, m.index_d, m.z_top_switch))

    def position_report(self) -> bytes:
        """Status bytes 139..171: X, Y, Z, B as float8 (NUL padded), then the tool."""
        x, y, z = (self.reported_position(a) for a in "XYZ")
        b = self.reported_position("B") * (-1 if self.tool == 1 else 1)
        return b"".join(report_float(v) for v in (x, y, z, b)) + b"%d" % self.tool

    def filament_report(self) -> bytes:
        """Status bytes 172..219: E and D diameters and multipliers, then the D and E
        feed-rate multipliers."""
        (ed, em), (dd, dm) = self.filament["E"], self.filament["D"]
        values = (ed, em, dd, dm, self.feed_multiplier["D"], self.feed_multiplier["E"])
        return b"".join(report_float(v) for v in values)

    def set_filament_info(self, extruder: str, raw: bytes) -> None:
        """0xc8/0xc9: diameter (at least 0.1) and multiplier (at least 0)."""
        self.filament[extruder] = [max(0.1, strtof(raw[:8])), max(0.0, strtof(raw[8:16]))]

    def set_feed_rate_multiplier(self, extruder: str, raw: bytes) -> None:
        self.feed_multiplier[extruder] = max(0.0, strtof(raw[:8]))

    # ------------------------------------------------------------- moves
    def select_tool(self, tool: int, line: Line | None = None) -> Iterator[Wait]:
        """T0/T1 (any other number is clamped): the valve axis counts as homed after it."""
        tool = max(0, min(2, tool))
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        self.tool = tool
        for axis in "XYZB":
            self.tool_offset[axis] = self._eeprom_offset(tool, axis)
        self.homed.add("B")
        yield from self._go(dict(self.logical))

    def set_position(self, line: Line) -> Iterator[Wait]:
        """G92: wait for motion, then X/Y/Z given are where the head is, and count as homed."""
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        for axis in "XYZ":
            if line.has(axis):
                self.logical[axis] = line.float(axis)
                self.position[axis] = float32(self.logical[axis] + self.tool_offset[axis])
                self.homed.add(axis)

    def delta_text(self, axis: str) -> bytes:
        return f"{axis}delta:{self.home_delta[axis]:f}\r\n".encode()

    def filament_mm(self, extruder: str, volume: float) -> float:
        """Volume (mm3) as filament length, in the firmware's float arithmetic."""
        diameter, multiplier = self.filament[extruder]
        return float32(float32(volume * multiplier) / (float32(diameter * diameter) * math.pi
                                                       / 4.0))

    def move(self, line: Line, rapid: bool = False) -> Iterator[Wait]:
        """G0/G1. X/Y/Z move only once homed (or set by G92), the valve B once a tool has
        been selected; E and D always. A move's target is kept even when it is dropped."""
        p = {c: line.float(c) for c in "XYZEDBF" if line.has(c)}
        if "F" in p:
            self.feed_rate = p["F"]
        target = dict(self.logical)
        distance = 0.0
        for axis in "XYZ":
            if axis in p:
                delta = p[axis] if self.relative else float32(p[axis] - self.logical[axis])
                target[axis] = float32(self.logical[axis] + delta)
                distance = float32(distance + float32(delta * delta))
        if "B" in p:
            target["B"] = p["B"]
        segments = 1 + int(float32(math.sqrt(distance)) / SEGMENT_MM)
        extrude = {e: self.filament_mm(e, p[e]) for e in "ED" if e in p}
        for e, mm in extrude.items():
            per = float32(mm / segments)
            for _ in range(segments):
                self.e_destination[e] = float32(self.e_destination[e] + per)
        speed = self.feed_rate / 60.0 if self.feed_rate > 0 else 1e9
        if rapid:
            speed = 1e9
        elif extrude:
            extruder = "D" if "D" in extrude and "E" not in extrude else "E"
            speed *= self.feed_multiplier[extruder]
        start = dict(self.logical)
        for n in range(1, segments + 1):
            for a in "XYZB":
                self.logical[a] = start[a] + (target[a] - start[a]) * n / segments
            yield from self._do_move({e: mm / segments for e, mm in extrude.items()}, speed)
        self.logical = target

    def _machine_target(self, axis: str) -> float:
        """Where the machine should be for the logical target: the firmware's do_move,
        travel limits and the valve's 0..1 range (flipped for tool 1) included."""
        dest = self.logical[axis] + self.tool_offset[axis] if axis != "B" else self.logical["B"]
        if axis in "XY":
            return max(0.0, min(TRAVEL[axis], dest))
        if axis == "Z":
            return min(TRAVEL["Z"], max(0.0, self.logical["Z"]) + self.tool_offset["Z"])
        opening = max(0.0, min(1.0, dest))
        return opening if self.tool == 0 else -opening

    def _do_move(self, extrude: dict[str, float], speed: float) -> Iterator[Wait]:
        moves = {a: self._machine_target(a) - self.position[a] if a in self.homed else 0.0
                 for a in "XYZB"}
        moves.update(extrude)
        yield from self._segment(moves, speed)

    def _segment(self, part: dict[str, float], speed: float) -> Iterator[Wait]:
        """Queue whole steps for `part` (mm); what is left over stays in the position
        bookkeeping (X/Y/Z/B) or the E/D residue, so it is carried into the next move."""
        steps = {}
        for axis, mm in part.items():
            if axis in "ED":
                mm += self.e_residue[axis]
            whole = math.floor(mm * self.steps_per_mm(axis) + 0.5)
            if whole:
                steps[axis] = whole
        if not steps:
            for axis in "ED":
                if axis in part:
                    self.e_residue[axis] += part[axis]
            return  # shorter than a step: absorbed into the next move
        for axis, mm in part.items():
            actual = float32(steps.get(axis, 0) / self.steps_per_mm(axis))
            if axis in "ED":
                self.e_residue[axis] = mm + self.e_residue[axis] - actual
            else:
                self.position[axis] = float32(self.position[axis] + actual)
        xyz = [steps.get(a, 0) / self.steps_per_mm(a) for a in "XYZ"]
        length = math.sqrt(sum(v * v for v in xyz))
        if length > 0:
            direction = tuple(v / length for v in xyz)
        else:
            length = max(abs(steps.get(a, 0)) / self.steps_per_mm(a) for a in "EDB")
            direction = (0.0, 0.0, 0.0)
        limits = self.fw.parameters.values["max_speed"]
        for axis, count in steps.items():
            axis_mm = abs(count) / self.steps_per_mm(axis)
            if axis_mm > 0 and length > 0:
                speed = min(speed, limits[axis] * length / axis_mm)
        motion = self.fw.motion
        yield from wait_for(motion.room, Wait(motion=True))
        motion.add(Block(steps, length, max(speed, 0.1), direction))

    def home(self, line: Line) -> Iterator[Wait]:
        """G28 with the axes named (G28 alone homes nothing): each runs towards its switch
        until it closes. Mechanics in detail belong to the machine model."""
        motion = self.fw.motion
        for axis in "XYZ":
            self.tool_offset[axis] = self._eeprom_offset(self.tool, axis)
        yield from wait_for(motion.idle, Wait(motion=True))
        for axis in "XYZ":
            if not line.has(axis):
                continue
            hw_axis = self.fw.hw.machine.axes[axis]
            distance = max(0, hw_axis.position) / self.steps_per_mm(axis)
            motion.add(Block({}, distance, HOMING_SPEED[axis], homing=axis))
            yield from wait_for(motion.idle, Wait(motion=True))
            self.position[axis] = 0.0
            self.logical[axis] = float32(-self.tool_offset[axis])
            self.homed.add(axis)

    def _go(self, target: dict[str, float]) -> Iterator[Wait]:
        """A rapid move of the homed axes to `target` (logical coordinates)."""
        self.logical = dict(target)
        yield from self._do_move({}, 1e9)

    def move_filament_until_slip(self, line: Line) -> Iterator[Wait]:
        """G36: with no filament at the sensor nothing moves."""
        machine = self.fw.hw.machine
        for extruder in "ED":
            if line.has(extruder):
                yield from wait_for(self.fw.motion.idle, Wait(motion=True))
                present = machine.filament_e if extruder == "E" else machine.filament_d
                if not present:
                    continue

    def unlock_cover(self, line: Line) -> Iterator[Wait]:
        """G37: heaters off and the bed left to cool first, unless S."""
        if not line.has("S"):
            self.fw.heaters.turn_off()
            yield from self.fw.heaters.wait_for_bed_cool()

    def level_gantry(self) -> Iterator[Wait]:
        """G38 needs two Z probe points; without them it does nothing."""
        if self.levelling_points < 2:
            return
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))

    def level_bed(self, line: Line) -> None:
        if line.has("S"):
            self.z_washout = line.float("S")
        else:
            self.levelling_points = 0

    def filament_load_unload(self, code: int, line: Line) -> Iterator[Wait]:
        """M120/M121/M122: the moves wait for the queue; loading needs filament."""
        for extruder in "ED":
            if line.has(extruder):
                yield from wait_for(self.fw.motion.idle, Wait(motion=True))

    def completed(self, block: Block) -> None:
        for extruder in "ED":
            if extruder in block.steps:
                mm = block.steps[extruder] / self.steps_per_mm(extruder)
                self.total_mm[extruder] += mm

    # ----------------------------------------------------- pause parking
    def park(self) -> Iterator[Wait]:
        """Wait for motion, remember where the job was, close the valve, lift Z 2 mm."""
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        self.unpark_state = {"logical": dict(self.logical), "feed_rate": self.feed_rate,
                             "relative": self.relative, "tool": self.tool}
        target = dict(self.logical)
        target["B"] = 0.0
        yield from self._go(target)
        target["Z"] += PARKING_Z
        yield from self._go(target)
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))

    def unpark(self) -> Iterator[Wait]:
        """Return to where the job was parked and restore its modes and tool."""
        state = self.unpark_state
        if state is None:
            return
        self.relative = state["relative"]
        self.feed_rate = state["feed_rate"]
        saved = state["logical"]
        target = dict(saved)
        target["B"] = min(self.logical["B"], saved["B"])
        if state["tool"] != self.tool:
            self.tool = state["tool"]
        yield from self._go(target)
        yield from self._go(dict(saved))


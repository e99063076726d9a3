"""Heaters: nozzle 0, nozzle 1, bed and ambient, PID-driven duty on first-order plants."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from robox.firmware.gcode import Wait, wait_for
from robox.formats.eeprom import EepromIndex
from robox.formats.float8 import encode as float8
from robox.formats.protocol import ErrorBit

CHANNELS = ("nozzle0", "nozzle1", "bed", "ambient")
THERMISTOR_ERROR = {"nozzle0": ErrorBit.NOZZLE0_THERMISTOR,
                    "nozzle1": ErrorBit.NOZZLE1_THERMISTOR, "bed": ErrorBit.BED_THERMISTOR}
GAINS = {"nozzle0": (0.08, 0.004, 0.3), "nozzle1": (0.08, 0.004, 0.3),
         "bed": (0.2, 0.002, 1.0), "ambient": (0.1, 0.001, 0.0)}
REACHED = 2.0  # degrees: a wait is over within this of the target
HOT = 60.0  # a nozzle above this is "hot" (head hours, powered off whilst hot)
OFF, NORMAL, FIRST_LAYER = 0, 1, 2


@dataclass
class Channel:
    name: str
    mode: int = OFF
    target: float = 0.0
    first_layer_target: float = 0.0
    integral: float = 0.0
    previous_error: float = 0.0

    @property
    def setpoint(self) -> float:
        if self.mode == OFF:
            return 0.0
        return self.first_layer_target if self.mode == FIRST_LAYER else self.target


class Heaters:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.channels = {name: Channel(name) for name in CHANNELS}
        self.waiting_for = "0"
        self.last_time = self.fw.clock.now
        self.fw.eeproms.on_valid.append(self._eeprom_valid)
        self.fw.eeproms.on_lost.append(self._eeprom_lost)

    def _eeprom_valid(self, index) -> None:
        if index == EepromIndex.REEL0:
            self.load_reel_targets()

    def _eeprom_lost(self, index) -> None:
        if index == EepromIndex.HEAD:
            self.all_off()

    def load_reel_targets(self) -> None:
        eeproms = self.fw.eeproms
        if eeproms.status(EepromIndex.REEL0) != 2:
            return
        get = lambda name: eeproms.get_float(EepromIndex.REEL0, name)  # noqa: E731
        nozzle, bed = self.channels["nozzle0"], self.channels["bed"]
        nozzle.target, nozzle.first_layer_target = get("nozzle_temperature"), \
            get("first_layer_nozzle_temperature")
        bed.target, bed.first_layer_target = get("bed_temperature"), \
            get("first_layer_bed_temperature")
        self.channels["ambient"].target = get("ambient_temperature")

    # ------------------------------------------------------------ control
    def maintain(self) -> None:
        now = self.fw.clock.now
        dt = now - self.last_time
        self.last_time = now
        machine = self.fw.hw.machine
        for name, channel in self.channels.items():
            plant = machine.heaters[name]
            if not plant.thermistor_ok and name in THERMISTOR_ERROR:
                self.fw.errors.set(THERMISTOR_ERROR[name])
                channel.mode = OFF
            setpoint = channel.setpoint
            if channel.mode == OFF or setpoint <= 0:
                plant.duty = 0.0
                channel.integral = 0.0
                continue
            kp, ki, kd = GAINS[name]
            error = setpoint - plant.temperature
            if dt > 0:
                channel.integral = max(-50.0, min(50.0, channel.integral + error * dt))
                derivative = (error - channel.previous_error) / dt
            else:
                derivative = 0.0
            channel.previous_error = error
            plant.duty = max(0.0, min(1.0, kp * error + ki * channel.integral * 10
                                      + kd * derivative * 0.01))

    def any_on(self) -> bool:
        return any(c.mode != OFF for c in self.channels.values())

    def all_off(self) -> None:
        for channel in self.channels.values():
            channel.mode = OFF
        for plant in self.fw.hw.machine.heaters.values():
            plant.duty = 0.0

    def head_hot(self) -> bool:
        heaters = self.fw.hw.machine.heaters
        return max(heaters["nozzle0"].temperature, heaters["nozzle1"].temperature) > HOT

    def reached(self, name: str) -> bool:
        channel = self.channels[name]
        return channel.mode == OFF or \
            abs(self.fw.hw.machine.heaters[name].temperature - channel.setpoint) <= REACHED

    def _wait(self, name: str, why: str) -> Iterator[Wait]:
        self.waiting_for = why
        yield from wait_for(lambda: self.reached(name), Wait(heater=name))
        self.waiting_for = "0"

    # ---------------------------------------------------------- G-codes
    def _set(self, name: str, p: dict, first_layer: bool = False) -> None:
        channel = self.channels[name]
        if "S" in p:
            if first_layer:
                channel.first_layer_target = p["S"]
            else:
                channel.target = p["S"]
        if not first_layer:
            channel.mode = NORMAL if channel.target > 0 else OFF

    def set_nozzle(self, p: dict, wait: bool) -> Iterator[Wait]:
        name = f"nozzle{int(p.get('T', self.fw.position.tool)) % 2}"
        self._set(name, p)
        if wait:
            yield from self._wait(name, "2" if name == "nozzle0" else "3")

    def set_first_layer_nozzle(self, p: dict) -> None:
        self._set(f"nozzle{int(p.get('T', self.fw.position.tool)) % 2}", p, first_layer=True)

    def set_bed(self, p: dict, wait: bool) -> Iterator[Wait]:
        self._set("bed", p)
        if wait:
            yield from self._wait("bed", "1")

    def set_first_layer_bed(self, p: dict) -> None:
        self._set("bed", p, first_layer=True)

    def set_ambient(self, p: dict) -> None:
        self._set("ambient", p)

    def set_targets(self, values: list[float]) -> None:
        """Command 0xc3: the seven targets, nozzle 0 first."""
        n0, n0f, n1, n1f, bed, bedf, ambient = values
        for name, target, first in (("nozzle0", n0, n0f), ("nozzle1", n1, n1f),
                                    ("bed", bed, bedf), ("ambient", ambient, None)):
            channel = self.channels[name]
            channel.target = target
            if first is not None:
                channel.first_layer_target = first

    # --------------------------------------------------------- reports
    def report_block(self) -> bytes:
        """Bytes 40..133 of the status report."""
        machine = self.fw.hw.machine
        out = bytearray()
        for name in ("nozzle0", "nozzle1", "bed"):
            channel = self.channels[name]
            out += str(channel.mode).encode()
            out += float8(machine.heaters[name].temperature, b"\0")
            out += float8(channel.target, b"\0") + float8(channel.first_layer_target, b"\0")
        ambient = self.channels["ambient"]
        out += str(ambient.mode).encode()
        out += float8(machine.heaters["ambient"].temperature, b"\0")
        out += float8(ambient.target, b"\0")
        out += b"1" if machine.head_fan > 0 else b"0"
        out += self.waiting_for.encode()
        return bytes(out)

    def m105_text(self) -> bytes:
        h = self.fw.hw.machine.heaters
        duty = {name: round(h[name].duty * 255) for name in CHANNELS}
        mains = "$"
        return (f"S:{int(h['nozzle0'].temperature)} @{duty['nozzle0']} "
                f"T:{int(h['nozzle1'].temperature)} @{duty['nozzle1']} "
                f"B:{int(h['bed'].temperature)} {mains}{duty['bed']} "
                f"A:{int(h['ambient'].temperature)} *{duty['ambient']}\r\n").encode()

"""The printer's mechanics and thermals as the firmware drives them: axes with home
switches, heaters with first-order thermal models, fans, LEDs, button, head power."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

AXES = "XYZEDB"


@dataclass
class Axis:
    """A stepper axis: position in microsteps; the home switch closes at or below zero."""

    name: str
    position: int = 0
    travel: int = 0  # steps of free travel above home; 0 = no end (E, D)
    has_switch: bool = True

    @property
    def switch(self) -> bool:
        return self.has_switch and self.position <= 0


@dataclass
class ThermalModel:
    """dT/dt = (gain * duty - (T - ambient)) / tau, integrated exactly for constant duty."""

    name: str
    gain: float  # degrees above ambient at full power
    tau: float  # seconds
    ambient: float = 20.0
    temperature: float = 20.0
    duty: float = 0.0  # 0..1
    thermistor_ok: bool = True

    def advance(self, seconds: float) -> None:
        target = self.ambient + self.gain * self.duty
        self.temperature = target + (self.temperature - target) * math.exp(-seconds / self.tau)


@dataclass
class Machine:
    """Everything physical the firmware touches, besides the card, chips, flash and USB."""

    axes: dict[str, Axis] = field(default_factory=lambda: {
        "X": Axis("X", 0, 210 * 134), "Y": Axis("Y", 0, 150 * 134), "Z": Axis("Z", 0, 100 * 6400),
        "E": Axis("E", has_switch=False), "D": Axis("D", has_switch=False),
        "B": Axis("B", 0, 2 * 2500)})
    heaters: dict[str, ThermalModel] = field(default_factory=lambda: {
        "nozzle0": ThermalModel("nozzle0", gain=253.0, tau=71.0),
        "nozzle1": ThermalModel("nozzle1", gain=253.0, tau=71.0),
        "bed": ThermalModel("bed", gain=150.0, tau=280.0),
        "ambient": ThermalModel("ambient", gain=40.0, tau=600.0)})
    head_fan: float = 0.0
    ambient_led: tuple[int, int, int] = (0, 0, 0)
    button_led: tuple[int, int, int] = (0, 0, 0)
    lid_closed: bool = True
    button_pressed: bool = False
    head_power: bool = True
    head_shorted: bool = False
    head_lights: bool = False
    filament_e: bool = False  # filament at the E / D sensor
    filament_d: bool = False
    index_e: bool = True  # index wheel input levels
    index_d: bool = False
    z_top_switch: bool = False
    supply_24v: bool = True
    hardware_revision: int = 2

    def advance(self, seconds: float) -> None:
        for heater in self.heaters.values():
            heater.advance(seconds)

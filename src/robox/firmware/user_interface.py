"""User interface: the ambient and button LEDs."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from robox.firmware.main import Firmware


class UserInterface:
    def __init__(self, firmware: Firmware):
        self.fw = firmware

    def initialise(self) -> None:
        pass

    def maintain(self) -> None:
        pass

    def set_led(self, ambient: bool, colour: tuple[int, int, int]) -> None:
        machine = self.fw.hw.machine
        if ambient:
            machine.ambient_led = colour
        else:
            machine.button_led = colour

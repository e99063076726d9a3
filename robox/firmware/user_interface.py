"""User interface: ambient and button LEDs, the button, head power, the "hot" flag.

The "powered off whilst hot" check needs a flag that survives power loss: the
model keeps it in nonvolatile byte 0 of the SD card directory (set while a
nozzle is above 60 °C, cleared when it cools), a place protocol.md leaves free.
"""

from __future__ import annotations

HOT_FLAG_BYTE = 0


class UserInterface:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.hot_recorded: bool | None = None

    def set_led(self, ambient: bool, colour: tuple[int, int, int]) -> None:
        machine = self.fw.hw.machine
        if ambient:
            machine.ambient_led = colour
        else:
            machine.button_led = colour

    def set_head_power(self, on: bool) -> None:
        self.fw.hw.machine.head_power = on
        if not on:
            self.fw.heaters.all_off()

    def maintain(self) -> None:
        hot = self.fw.heaters.head_hot()
        if hot != self.hot_recorded and self.fw.hw.card.present and \
                self.fw.file_system.set_nonvolatile(HOT_FLAG_BYTE, int(hot)):
            self.hot_recorded = hot

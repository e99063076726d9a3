"""Extension modules for the opt-in compiled core (see buildsys/robox_build.py); the
rest of the package's metadata is in pyproject.toml."""

import os

from setuptools import setup

# The firmware model's per-pass work: the loop, the step interrupt and block queue,
# segmenting and positions, G-code, commands, EEPROMs, heaters, C arithmetic and line
# parsing, the machine the steps move, the EEPROMs' bus and chips, the USB link, the
# clock, the filament float format; and the host's G-code translator.
NATIVE_MODULES = [
    "robox/firmware/carith.py",
    "robox/firmware/cline.py",
    "robox/firmware/motion.py",
    "robox/firmware/position.py",
    "robox/firmware/heaters.py",
    "robox/firmware/main.py",
    "robox/firmware/gcode.py",
    "robox/firmware/command.py",
    "robox/firmware/eeprom.py",
    "robox/firmware/parameters.py",
    "robox/firmware/error_flags.py",
    "robox/firmware/user_interface.py",
    "robox/hardware/machine.py",
    "robox/hardware/eeprom_bus.py",
    "robox/hardware/clock.py",
    "robox/hardware/usb.py",
    "robox/hardware/eeprom.py",
    "robox/formats/float8.py",
    "robox/gcode/translate.py",
    "robox/gcode/text.py",
]


def ext_modules():
    if os.environ.get("ROBOX_NATIVE") != "1":
        return []
    from mypyc.build import mypycify

    # the modules they import are type-checked only as far as the compiled ones need
    options = ["--ignore-missing-imports", "--follow-imports=silent"]
    return mypycify(options + NATIVE_MODULES, opt_level="3")


setup(ext_modules=ext_modules())

"""Extension modules for the compiled core (buildsys/robox_build.py decides whether a
build has them); the rest of the package's metadata is in pyproject.toml."""

import os

from setuptools import setup

# The firmware model's per-pass work: the loop, the step interrupt and block queue,
# segmenting and positions, G-code, commands, EEPROMs, heaters, C arithmetic and line
# parsing, the machine the steps move, the EEPROMs' bus and chips, the USB link, the
# clock, the filament float format; and the host's G-code translator and valve stage.
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
    "robox/hardware/deposition.py",
    "robox/hardware/eeprom_bus.py",
    "robox/hardware/clock.py",
    "robox/hardware/usb.py",
    "robox/hardware/eeprom.py",
    "robox/hardware/faults.py",
    "robox/hardware/sdcard.py",
    "robox/formats/float8.py",
    "robox/gcode/translate.py",
    "robox/gcode/valve.py",
    "robox/gcode/text.py",
    "robox/packed.py",
]


NATIVE = os.environ.get("ROBOX_BUILD_KIND") == "native"


def ext_modules():
    if not NATIVE:
        return []
    from mypyc.build import mypycify

    # the modules they import are type-checked only as far as the compiled ones need
    # COMPILED (robox/packed.py) always true: the compiled modules use librt's vectors
    options = ["--ignore-missing-imports", "--follow-imports=silent", "--always-true=COMPILED",
               "--cache-dir", os.path.join("build", "native", "mypy-cache")]
    return mypycify(options + NATIVE_MODULES, opt_level="3",
                    target_dir=os.path.join("build", "native", "c"))


# a build directory of its own for each kind: a pure wheel never packs an extension that
# a compiled build left in build/lib
setup(ext_modules=ext_modules(),
      options={"build": {"build_base": os.path.join("build", "native" if NATIVE else "pure")}})

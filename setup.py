"""Extension modules for the compiled core (buildsys/robox_build.py decides whether a
build has them); the rest of the package's metadata is in pyproject.toml."""

import os

from robox_build import BuildExt, stage  # buildsys/, the build backend's own directory
from setuptools import setup

# The firmware model's per-pass work: the loop, the step interrupt and block queue,
# segmenting and positions, G-code, commands, EEPROMs, heaters, C arithmetic and line
# parsing, the machine the steps move, the EEPROMs' bus and chips, the USB link, the
# clock, the filament float format; the host's G-code translator and valve stage; and
# what simulate watches at every queued move and pass.
NATIVE_MODULES = [
    "src/robox/firmware/carith.py",
    "src/robox/firmware/cline.py",
    "src/robox/firmware/motion.py",
    "src/robox/firmware/position.py",
    "src/robox/firmware/heaters.py",
    "src/robox/firmware/main.py",
    "src/robox/firmware/gcode.py",
    "src/robox/firmware/command.py",
    "src/robox/firmware/eeprom.py",
    "src/robox/firmware/file_system.py",
    "src/robox/firmware/parameters.py",
    "src/robox/firmware/error_flags.py",
    "src/robox/firmware/user_interface.py",
    "src/robox/hardware/machine.py",
    "src/robox/hardware/deposition.py",
    "src/robox/hardware/eeprom_bus.py",
    "src/robox/hardware/clock.py",
    "src/robox/hardware/usb.py",
    "src/robox/hardware/eeprom.py",
    "src/robox/hardware/faults.py",
    "src/robox/hardware/sdcard.py",
    "src/robox/formats/float8.py",
    "src/robox/gcode/translate.py",
    "src/robox/gcode/valve.py",
    "src/robox/gcode/text.py",
    "src/robox/sim/watch.py",
    "src/robox/sim/quality.py",
    "src/robox/packed.py",
]


NATIVE = os.environ.get("ROBOX_BUILD_KIND") == "native"


def ext_modules():
    if not NATIVE:
        return []
    from mypyc.build import mypycify

    # the modules they import are type-checked only as far as the compiled ones need
    # COMPILED (src/robox/packed.py) always true: the compiled modules use librt's vectors
    options = ["--ignore-missing-imports", "--follow-imports=silent", "--always-true=COMPILED",
               "--cache-dir", os.path.join("build", "native", "mypy-cache")]
    # one C file per module (multi_file): robox_build.BuildExt compiles them side by side,
    # and with GCC optimises them as one program at link time
    with stage(f"compiled core: type-checking {len(NATIVE_MODULES)} modules and writing "
               "their C"):
        return mypycify(options + NATIVE_MODULES, opt_level="3", multi_file=True,
                        target_dir=os.path.join("build", "native", "c"))


# a build directory of its own for each kind: a pure wheel never packs an extension that
# a compiled build left in build/lib
setup(ext_modules=ext_modules(), cmdclass={"build_ext": BuildExt},
      options={"build": {"build_base": os.path.join("build", "native" if NATIVE else "pure")}})

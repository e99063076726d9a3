"""Which of the hot modules (the firmware model's, the host's G-code translator, and what
simulate watches) run compiled.

A wheel build (`pip install .`) compiles them with mypyc where a C compiler is
(buildsys/robox_build.py, setup.py); an editable install, `ROBOX_NATIVE=0` or a machine
where compiling fails runs the same modules as pure Python. Both give the same bytes,
positions and moments; the compiled ones only run faster. `robox-cli --version` reports
describe()."""

from __future__ import annotations

import importlib

MODULES = (
    "robox.firmware.carith",
    "robox.firmware.cline",
    "robox.firmware.motion",
    "robox.firmware.position",
    "robox.firmware.heaters",
    "robox.firmware.main",
    "robox.firmware.gcode",
    "robox.firmware.command",
    "robox.firmware.eeprom",
    "robox.firmware.file_system",
    "robox.firmware.parameters",
    "robox.firmware.error_flags",
    "robox.firmware.user_interface",
    "robox.hardware.machine",
    "robox.hardware.deposition",
    "robox.hardware.eeprom_bus",
    "robox.hardware.clock",
    "robox.hardware.usb",
    "robox.hardware.eeprom",
    "robox.hardware.faults",
    "robox.hardware.sdcard",
    "robox.formats.float8",
    "robox.gcode.translate",
    "robox.gcode.valve",
    "robox.gcode.text",
    "robox.sim.watch",
    "robox.sim.quality",
    "robox.packed",
)


def compiled_modules() -> list[str]:
    """The modules of MODULES loaded from a compiled extension."""
    out = []
    for name in MODULES:
        path = getattr(importlib.import_module(name), "__file__", None) or ""
        if not path.endswith(".py"):
            out.append(name)
    return out


def optimisation(path: str | None = None) -> str | None:
    """How the build optimised the compiled core beyond mypyc's C, as it recorded it in
    the package (buildsys/robox_build.py; `path`: another record): at link time, from a
    training run's profile, or neither; None where it recorded nothing (a pure build)."""
    import json
    from pathlib import Path

    path = path or str(Path(__file__).with_name("native_build.json"))
    try:
        built = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(built, dict):
        return None
    done = [name for key, name in (("link_time", "at link time"),
                                   ("profile", "from a training run's profile"))
            if built.get(key) is True]
    return "optimised " + " and ".join(done) if done else "compiled file by file"


def describe() -> str:
    n = len(compiled_modules())
    if n == 0:
        return "pure Python"
    how = optimisation()
    return f"compiled core ({n} of {len(MODULES)} modules{', ' + how if how else ''})"


def build() -> str:
    """Which robox this is: version, build, and where it was imported from (for the
    figures a benchmark prints)."""
    import importlib.metadata
    from pathlib import Path

    try:
        version = importlib.metadata.version("robox")
    except importlib.metadata.PackageNotFoundError:
        version = "(not installed)"
    where = Path(importlib.import_module("robox").__file__ or "?").parent
    return f"robox {version}, {describe()}, from {where}"

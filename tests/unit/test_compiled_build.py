"""The compiled core, built here as a plain `pip install .` builds it (compiled is the
default where a C compiler is), runs the firmware model's own tests with the same
results as pure Python.

mypyc compiles the same sources with other semantics in places (native integers,
declared attribute types checked on assignment, classes whose methods cannot be
replaced): this is the run that sees a difference those make. It builds a wheel from a
copy of the sources (the working tree gets no build directory), unpacks it and runs
tests/firmware, tests/sim, the translator's tests, the EEPROM unplug campaign and the
native arithmetic tests against it, from a directory without the sources, so the
compiled modules are the ones imported.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from robox.native import MODULES

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ("robox", "buildsys", "setup.py", "pyproject.toml", "README.md")
SUITES = ("tests/firmware", "tests/sim", "tests/gcode", "tests/faults/test_print_eeprom_unplug.py",
          "tests/unit/test_native.py")


def _compiler() -> str | None:
    cc = (sysconfig.get_config_var("CC") or "cc").split()[0]
    return shutil.which(cc)


def copy_project(names: tuple[str, ...], dest: Path, *skip: str) -> None:
    """The project's files and directories `names` into `dest`, without `skip`."""
    for name in names:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns(*skip))
        else:
            shutil.copy2(src, dest / name)


@pytest.mark.skipif(_compiler() is None, reason="needs a C compiler for mypyc")
def test_the_compiled_core_passes_the_firmware_models_tests(tmp_path):
    src, wheels, site, run = (tmp_path / d for d in ("src", "wheel", "site", "run"))
    copy_project(SOURCES, src, "__pycache__", "*.so", "*.pyd", "build", "*.egg-info")
    env = {k: v for k, v in os.environ.items() if k != "ROBOX_NATIVE"}  # the default
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                            "-w", str(wheels), str(src)],
                           env=env, capture_output=True, text=True, timeout=900)
    assert built.returncode == 0, built.stderr[-4000:]
    (wheel,) = wheels.glob("robox-*.whl")
    assert "-none-any" not in wheel.name  # a platform wheel: extensions inside
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    # what the build wrote stays in build/ (mypy's cache and mypyc's C sources too)
    written = {p.name for p in src.iterdir()} - set(SOURCES)
    assert written == {"build", "robox.egg-info"}, written

    # a pure build from the same tree afterwards packs no extension the compiled one left
    pure = tmp_path / "pure"
    again = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                            "-w", str(pure), str(src)], env=dict(env, ROBOX_NATIVE="0"),
                           capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-4000:]
    (plain,) = pure.glob("robox-*.whl")
    assert plain.name.endswith("-py3-none-any.whl")
    with zipfile.ZipFile(plain) as z:
        assert not [n for n in z.namelist() if n.endswith((".so", ".pyd"))]

    # the tests and what they read by path from the project's root; no package sources
    run.mkdir()
    copy_project(("tests", "bench", "buildsys", "setup.py", "pyproject.toml", "README.md",
           "robox/data"), run, "__pycache__", ".cache")
    env = {k: v for k, v in os.environ.items() if k != "ROBOX_NATIVE"}
    env["PYTHONPATH"] = str(site)

    which = subprocess.run(
        [sys.executable, "-c", "import robox, robox.native as n; print(robox.__file__); "
                               "print(len(n.compiled_modules()))"],
        cwd=run, env=env, capture_output=True, text=True, timeout=120)
    assert which.returncode == 0, which.stderr
    path, count = which.stdout.split()
    assert Path(path).is_relative_to(site)
    assert int(count) == len(MODULES)

    tested = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             *SUITES], cwd=run, env=env, capture_output=True, text=True,
                            timeout=900)
    assert tested.returncode == 0, tested.stdout[-6000:] + tested.stderr[-2000:]
    assert " passed" in tested.stdout.splitlines()[-1]

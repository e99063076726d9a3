"""What the tests run, and the pure-Python fallback.

The test command (README) installs the package as a user's `pip install .` does, the
compiled core where a C compiler is, and the tests import that installed package: the
sources live under src/, out of reach of the working directory. Here: that this holds,
that such an install has every hot module compiled, and that the pure-Python build a
machine without a compiler gets passes the firmware model's own tests (tests/firmware,
tests/sim, the translator's, the EEPROM unplug campaign, the native arithmetic tests),
run from a directory without the sources against a pure wheel of this tree.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

import robox
from robox.native import MODULES, compiled_modules

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ("src", "buildsys", "setup.py", "pyproject.toml", "README.md", "MANIFEST.in")
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


def _editable() -> bool:
    """Whether the package under test is an editable install of this tree."""
    try:
        text = importlib.metadata.distribution("robox").read_text("direct_url.json")
    except importlib.metadata.PackageNotFoundError:
        return False
    return bool(text) and bool(json.loads(text).get("dir_info", {}).get("editable"))


def test_the_tests_import_the_installed_package():
    """The tests exercise what `pip install .` installed (the compiled core where a C
    compiler is), never the source tree by accident of the working directory."""
    source = (ROOT / "src").resolve()
    imported = Path(robox.__file__).resolve()
    if imported.is_relative_to(source):
        assert _editable(), f"robox was imported from the source tree ({imported})"
        return
    assert importlib.metadata.distribution("robox").locate_file("robox/__init__.py") \
        .resolve() == imported


@pytest.mark.skipif(_compiler() is None or _editable() or os.environ.get("ROBOX_NATIVE") == "0",
                    reason="a compiled install needs a C compiler and a wheel build")
def test_an_install_where_a_compiler_is_has_every_hot_module_compiled():
    assert compiled_modules() == list(MODULES)


def _gcc() -> bool:
    """Whether the build's compiler is GCC (which the build optimises at link time and
    from a training run: buildsys/robox_build.py)."""
    cc = _compiler()
    if cc is None:
        return False
    run = subprocess.run([cc, "-dM", "-E", "-"], input="", capture_output=True, text=True)
    return run.returncode == 0 and "__GNUC__" in run.stdout and "__clang__" not in run.stdout


@pytest.mark.skipif(not _gcc() or _editable() or os.environ.get("ROBOX_NATIVE") == "0",
                    reason="the training run is GCC's, in a wheel build")
def test_a_gcc_install_runs_the_core_compiled_from_its_training_runs_profile():
    """The core a user runs is the one compiled again with the counts, never the one
    with the counters in it (slower, and it would write its counts at every exit)."""
    from robox.native import optimisation

    assert optimisation() == "optimised at link time and from a training run's profile"
    cores = [m for name, m in sys.modules.items() if name.endswith("__mypyc")]
    assert cores, "no compiled core library is loaded"
    for core in cores:
        assert b"__gcov_" not in Path(core.__file__).read_bytes(), core.__file__


def test_the_training_run_passes_on_the_installed_package(tmp_path):
    """buildsys/robox_train.py, which a GCC build runs on its instrumented core, on the
    package installed here: its commands succeed, and its job prints cleanly through
    the valve stage (a job the translator refused or the printer stopped on would train
    the build on the wrong paths)."""
    package = Path(robox.__file__).resolve().parent.parent
    work = tmp_path / "work"
    work.mkdir()
    run = subprocess.run([sys.executable, str(ROOT / "buildsys" / "robox_train.py"),
                          str(package), str(work)], capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    job = work / "train.gcode"
    assert 15_000 < len(job.read_bytes().splitlines()) < 40_000
    report = subprocess.run([sys.executable, "-m", "robox.cli", "simulate", str(job),
                             "--json"], capture_output=True, text=True, timeout=600,
                            cwd=tmp_path)
    assert report.returncode == 0, report.stderr[-2000:]
    printed = json.loads(report.stdout)
    assert printed["translation"]["slicer"] == "PrusaSlicer"
    assert printed["translation"]["valve_cycles"] > 50
    assert printed["completed"] and printed["lines_run"] == printed["lines"]
    assert printed["errors"] == [] and printed["warnings"] == []
    assert printed["deposition"]["blobs"] == 0


def test_the_pure_python_fallback_passes_the_firmware_models_tests(tmp_path):
    """What a machine without a C compiler installs: the same sources, run as Python.
    Built from a copy of this tree with whatever build/ an earlier compiled install left
    there: the pure wheel packs none of its extensions."""
    src, wheels, site, run = (tmp_path / d for d in ("src", "wheel", "site", "run"))
    copy_project(SOURCES, src, "__pycache__", "*.egg-info")
    if (ROOT / "build").is_dir():
        shutil.copytree(ROOT / "build", src / "build", symlinks=True)
    env = dict(os.environ, ROBOX_NATIVE="0")
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                            "-w", str(wheels), str(src)],
                           env=env, capture_output=True, text=True, timeout=900)
    assert built.returncode == 0, built.stderr[-4000:]
    (wheel,) = wheels.glob("robox-*.whl")
    assert wheel.name.endswith("-py3-none-any.whl")
    with zipfile.ZipFile(wheel) as z:
        assert not [n for n in z.namelist() if n.endswith((".so", ".pyd"))]
        z.extractall(site)

    # the tests and what they read by path from the project's root; no package sources
    run.mkdir()
    copy_project(("tests", "bench", "buildsys", "setup.py", "pyproject.toml", "README.md",
                  "fixtures"), run, "__pycache__", ".cache")
    env = {k: v for k, v in os.environ.items() if k != "ROBOX_NATIVE"}
    env["PYTHONPATH"] = str(site)
    which = subprocess.run(
        [sys.executable, "-c", "import robox, robox.native as n; print(robox.__file__); "
                               "print(len(n.compiled_modules()))"],
        cwd=run, env=env, capture_output=True, text=True, timeout=120)
    assert which.returncode == 0, which.stderr
    path, count = which.stdout.split()
    assert Path(path).is_relative_to(site)
    assert int(count) == 0

    tested = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             *SUITES], cwd=run, env=env, capture_output=True, text=True,
                            timeout=1800)
    assert tested.returncode == 0, tested.stdout[-6000:] + tested.stderr[-2000:]
    assert " passed" in tested.stdout.splitlines()[-1]

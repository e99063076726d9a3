"""`pip` builds the package compiled where it can and pure Python where it cannot
(buildsys/robox_build.py): a machine without a working C compiler still installs, and
says why its package is pure; `ROBOX_NATIVE=1` makes the compiled core a requirement
and `ROBOX_NATIVE=0` turns it off.

Each test builds a wheel from a copy of the sources, as `pip install .` would, with the
compiler (CC) missing or failing; the compiled install itself is tested in
test_pure_build.py (every hot module compiled; with GCC, the core compiled from its
training run's profile, and the training run itself).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.unit.test_pure_build import SOURCES, copy_project


def _build(tmp_path: Path, **env_changes: str | None) -> tuple[subprocess.CompletedProcess,
                                                               list[Path]]:
    """`pip wheel -v` of a copy of the sources with the environment changed as given
    (None removes a variable); the run and the wheels it made."""
    src, wheels = tmp_path / "src", tmp_path / "wheels"
    src.mkdir()
    copy_project(SOURCES, src, "__pycache__", "*.so", "*.pyd", "build", "*.egg-info")
    env = dict(os.environ)
    for key, value in env_changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    run = subprocess.run([sys.executable, "-m", "pip", "wheel", "-v", "--no-deps",
                          "-w", str(wheels), str(src)],
                         env=env, capture_output=True, text=True, timeout=900)
    return run, sorted(wheels.glob("robox-*.whl"))


def _pure_wheel(wheel: Path) -> None:
    """A wheel for any platform with every module as source and no extension."""
    assert wheel.name.endswith("-py3-none-any.whl"), wheel.name
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    assert not [n for n in names if n.endswith((".so", ".pyd"))]
    for module in ("robox/firmware/main.py", "robox/firmware/motion.py",
                   "robox/gcode/translate.py", "robox/native.py"):
        assert module in names


def _said(run: subprocess.CompletedProcess) -> list[str]:
    """The backend's own lines (pip -v indents what the backend prints)."""
    return [line.strip() for line in (run.stdout + run.stderr).splitlines()
            if line.strip().startswith("robox:")]


def test_without_a_compiler_the_package_is_pure_and_says_why(tmp_path):
    run, wheels = _build(tmp_path, CC=str(tmp_path / "no-such-cc"), ROBOX_NATIVE=None)
    assert run.returncode == 0, run.stderr[-3000:]
    (wheel,) = wheels
    _pure_wheel(wheel)
    said = _said(run)
    assert len(said) == 1 and said[0].startswith("robox: no C compiler found"), said
    # nothing was compiled, so nothing was checked by mypy either
    assert not (tmp_path / "src" / "build" / "native").exists()


@pytest.mark.skipif(shutil.which("false") is None, reason="needs false(1) as a failing CC")
def test_a_compiler_that_fails_leaves_a_pure_package(tmp_path):
    run, wheels = _build(tmp_path, CC="false", ROBOX_NATIVE=None)
    assert run.returncode == 0, run.stderr[-3000:]
    (wheel,) = wheels
    _pure_wheel(wheel)
    said = _said(run)
    assert len(said) == 1, said
    assert said[0].startswith("robox: the compiled core did not build (")
    assert said[0].endswith("); building the pure-Python package")
    assert len(said[0]) < 300  # the compiler's whole command line is cut short


@pytest.mark.skipif(shutil.which("false") is None, reason="needs false(1) as a failing CC")
def test_a_required_compiled_core_that_fails_fails_the_build(tmp_path):
    run, wheels = _build(tmp_path, CC="false", ROBOX_NATIVE="1")
    assert run.returncode != 0
    assert wheels == []
    assert not [line for line in _said(run) if "pure-Python" in line]


def test_pure_on_request_needs_no_compiler(tmp_path):
    run, wheels = _build(tmp_path, CC=str(tmp_path / "no-such-cc"), ROBOX_NATIVE="0")
    assert run.returncode == 0, run.stderr[-3000:]
    (wheel,) = wheels
    _pure_wheel(wheel)
    assert _said(run) == []  # asked for: nothing to explain


def test_an_unknown_choice_is_refused_by_name(tmp_path):
    run, wheels = _build(tmp_path, ROBOX_NATIVE="yes")
    assert run.returncode != 0
    assert wheels == []
    assert "robox: ROBOX_NATIVE must be 1, 0 or auto, not 'yes'" in run.stdout + run.stderr


def test_the_sdist_carries_the_build_backend_and_its_training_run(tmp_path):
    """A wheel built from the sdist (`python -m build`) runs the same backend: it and the
    training run it starts travel in the sdist (MANIFEST.in)."""
    import tarfile

    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    copy_project(SOURCES, src, "__pycache__", "*.so", "*.pyd", "build", "*.egg-info")
    run = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, 'buildsys');"
                          " import robox_build; print(robox_build.build_sdist(sys.argv[1]))",
                          str(out)], cwd=src, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    (sdist,) = out.glob("robox-*.tar.gz")
    with tarfile.open(sdist) as tar:
        names = {name.split("/", 1)[1] for name in tar.getnames() if "/" in name}
    assert {"buildsys/robox_build.py", "buildsys/robox_train.py", "setup.py",
            "pyproject.toml"} <= names

"""How buildsys/robox_build.py's BuildExt optimises the compiled core with GCC: compiled
with counters, a training run, compiled again with the counts, at link time; and what
it does when the training run fails. Run here on a small library of two C files (the
core) and a one-file shim, with the real compiler and a training script of the test's
own that calls the core through ctypes, so each build takes a second, not minutes.
"""

from __future__ import annotations

import ctypes
import importlib
import json
import sys
from pathlib import Path

import pytest

from tests.unit.test_pure_build import _gcc

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(not _gcc(), reason="the profile-guided build is GCC's")

CORE_A = """
int step(int x);
__attribute__((visibility("default"))) int work(int n) {
    int total = 0;
    for (int i = 0; i < n; i++)
        total += (i % 7 == 0) ? step(i) : 1;
    return total;
}
"""
CORE_B = "int step(int x) { return x * 3 + 1; }\n"
SHIM = "int shim(void) { return 7; }\n"

TRAINER = """
import ctypes, sys
from pathlib import Path
if "{fail}":
    raise SystemExit("training run: {fail}")
(core,) = Path(sys.argv[1]).glob("core*.so")
assert ctypes.CDLL(str(core)).work(1000) == {expected}
"""


def _expected(n: int) -> int:
    return sum(3 * i + 1 if i % 7 == 0 else 1 for i in range(n))


@pytest.fixture
def backend(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "buildsys"))
    sys.modules.pop("robox_build", None)
    module = importlib.import_module("robox_build")
    monkeypatch.setattr(module, "_terminal", lambda: None)  # stages on stderr
    monkeypatch.setattr(module, "C_BODIES", {})  # (mypyc's functions: none here)
    return module


def _build(backend, monkeypatch, tmp_path: Path, fail: str = "") -> Path:
    """BuildExt on the small core and shim; the build's library directory."""
    from setuptools import Distribution, Extension

    src = tmp_path / "src"
    src.mkdir()
    for name, text in (("a.c", CORE_A), ("b.c", CORE_B), ("shim.c", SHIM)):
        (src / name).write_text(text)
    trainer = tmp_path / "train.py"
    trainer.write_text(TRAINER.format(fail=fail, expected=_expected(1000)))
    monkeypatch.setattr(backend, "TRAINER", str(trainer))
    flags = ["-O2", "-Werror"]  # as mypyc gives its C: a warning fails the compile
    dist = Distribution({"name": "probe", "ext_modules": [
        Extension("core", [str(src / "a.c"), str(src / "b.c")], extra_compile_args=flags),
        Extension("shim", [str(src / "shim.c")], extra_compile_args=flags)]})
    command = backend.BuildExt(dist)
    command.build_lib = str(tmp_path / "lib")
    command.build_temp = str(tmp_path / "temp")
    command.ensure_finalized()
    command.run()
    return tmp_path / "lib"


def _record(lib: Path) -> dict:
    return json.loads((lib / "robox" / "native_build.json").read_text())


def _core(lib: Path) -> Path:
    (core,) = lib.glob("core*.so")
    return core


def test_the_core_is_compiled_again_from_its_training_runs_counts(backend, monkeypatch,
                                                                   tmp_path, capsys):
    lib = _build(backend, monkeypatch, tmp_path)
    assert _record(lib) == {"link_time": True, "profile": True}
    said = capsys.readouterr().err
    assert "compiled core: the training run: done" in said
    assert "robox:" not in said  # nothing went wrong, nothing to explain
    # the training run counted (the counters wrote beside the objects) ...
    assert sorted(p.name for p in (tmp_path / "temp").rglob("*.gcda")) == ["a.gcda", "b.gcda"]
    # ... and what is left to run is the core compiled with the counts, not with counters
    core = _core(lib)
    assert b"__gcov_" not in core.read_bytes()
    assert ctypes.CDLL(str(core)).work(1000) == _expected(1000)
    assert (lib / next(p.name for p in lib.glob("shim*.so"))).exists()


def test_a_training_run_that_fails_leaves_a_core_optimised_at_link_time(backend, monkeypatch,
                                                                        tmp_path, capsys):
    lib = _build(backend, monkeypatch, tmp_path, fail="boom")
    assert _record(lib) == {"link_time": True, "profile": False}
    notes = [line for line in capsys.readouterr().err.splitlines()
             if line.startswith("robox:")]
    assert notes == ["robox: the training run failed (training run: boom); the core is "
                     "compiled without its profile"]
    core = _core(lib)
    assert b"__gcov_" not in core.read_bytes()
    assert ctypes.CDLL(str(core)).work(1000) == _expected(1000)


def test_counts_an_earlier_build_left_are_not_added_to(backend, monkeypatch, tmp_path):
    """The counters add to the files they find: a second build in the same tree starts
    from none, so its profile is its own training run's."""
    lib = _build(backend, monkeypatch, tmp_path)
    counts = sorted((tmp_path / "temp").rglob("*.gcda"))
    first = [p.read_bytes()[12:] for p in counts]  # (past the magic, version and stamp)
    (tmp_path / "src").rename(tmp_path / "src-was")
    (tmp_path / "train.py").unlink()
    _build(backend, monkeypatch, tmp_path)
    assert [p.read_bytes()[12:] for p in counts] == first
    assert _record(lib) == {"link_time": True, "profile": True}

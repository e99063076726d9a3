"""The compiled core's modules pass the type check mypyc runs before it compiles them.

A wheel build that fails it falls back to pure Python without a word in the
test run (buildsys/robox_build.py): this test is where such a change shows."""

import subprocess
import sys
from pathlib import Path

import pytest

from robox.native import MODULES

ROOT = Path(__file__).resolve().parent.parent


def test_the_compiled_modules_type_check_as_the_build_does(tmp_path):
    pytest.importorskip("mypy")
    paths = [str(Path(*name.split(".")).with_suffix(".py")) for name in MODULES]
    # the options setup.py gives mypyc
    check = subprocess.run(
        [sys.executable, "-m", "mypy", "--ignore-missing-imports", "--follow-imports=silent",
         "--cache-dir", str(tmp_path / "cache"), *paths],
        cwd=ROOT, capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr

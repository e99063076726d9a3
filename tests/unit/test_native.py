"""The opt-in compiled core: what setup.py compiles is what robox.native reports on."""

import ast
import importlib
import os
import sys
from pathlib import Path

import pytest

from robox import native

ROOT = Path(__file__).resolve().parents[2]


def setup_modules() -> list[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and node.targets[0].id == "NATIVE_MODULES":
            return [p.removesuffix(".py").replace("/", ".") for p in ast.literal_eval(node.value)]
    raise AssertionError("setup.py has no NATIVE_MODULES")


def test_the_compiled_modules_are_the_ones_robox_native_knows():
    assert setup_modules() == list(native.MODULES)


@pytest.mark.parametrize("name", native.MODULES)
def test_each_module_reports_how_it_runs(name):
    module = importlib.import_module(name)
    assert (name in native.compiled_modules()) == (not module.__file__.endswith(".py"))


def test_describe_counts_the_compiled_modules():
    n = len(native.compiled_modules())
    text = native.describe()
    whole = len(native.MODULES)
    assert (text == "pure Python") if n == 0 else text.startswith(f"compiled core ({n} of {whole}")


def test_the_build_backend_asks_for_mypyc_only_when_told_to(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "buildsys"))
    sys.modules.pop("robox_build", None)
    backend = importlib.import_module("robox_build")
    seen = []
    monkeypatch.setattr(backend._setuptools, "get_requires_for_build_wheel",
                        lambda settings=None: seen.append(os.environ.get("ROBOX_NATIVE"))
                        or ["wheel"])
    monkeypatch.delenv("ROBOX_NATIVE", raising=False)
    assert backend.get_requires_for_build_wheel() == ["wheel"]
    monkeypatch.setenv("ROBOX_NATIVE", "1")
    assert backend.get_requires_for_build_wheel() == ["wheel", backend.MYPYC]
    # setup.py is run without mypyc while the requirements are listed, then it is back on
    assert seen == [None, "0"] and os.environ["ROBOX_NATIVE"] == "1"

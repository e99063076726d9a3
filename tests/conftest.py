"""Shared test set-up. The helpers that bench/ scripts use too live in tests/cards.py
(no pytest there: a bench runs after the first command, which installs no pytest)."""

from __future__ import annotations

import importlib

from robox.cli import LAZY_COMMANDS

# tests.cards loads numpy before any test activates pyfakefs: robox imports numpy
# lazily, and numpy cannot be first imported from inside a fake file system
from tests.cards import pattern, read_back, upload  # noqa: F401 (imported from here too)

# robox-cli imports a command's module when the command runs: here, before any test
# runs one inside pyfakefs, which cannot patch a module first imported under it
for _module, _attribute, _help in LAZY_COMMANDS.values():
    importlib.import_module(_module)


import pytest  # noqa: E402

#: The tests that take minutes (the pure-Python build runs the model's tests again) or tens
#: of seconds (each builds a wheel). They run first: when the suite is spread over the
#: machine's cores (README: pytest -n auto), none is then left running alone at the end.
FIRST = ("tests/unit/test_pure_build.py", "tests/unit/test_build_kinds.py")


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: not item.nodeid.startswith(FIRST))  # (a stable sort)


@pytest.fixture(autouse=True)
def _own_state_home(tmp_path_factory, monkeypatch):
    """What the host records of printers' cards (robox.host.catalogue) stays in the test's
    own directory, never the user's; so do the notes of the printers it serves (a test
    running beside it that lists printers would find them)."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("state-home")))
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path_factory.mktemp("runtime")))

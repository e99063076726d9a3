"""The build backend: setuptools, plus an opt-in compiled core.

With ROBOX_NATIVE=1 in the environment, a (non-editable) install compiles the
firmware model's hot modules (setup.py, NATIVE_MODULES) with mypyc into C
extensions; the same .py files stay beside them as the pure-Python fallback, and
`robox.native.describe()` tells which one runs. Without it, or for an editable
install (whose compiled modules would shadow later edits of the sources), the
package is pure Python as always.
"""

import os
import sys

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the standard hooks, unchanged)

MYPYC = "mypy[mypyc]>=1.10"


def _native() -> bool:
    return os.environ.get("ROBOX_NATIVE") == "1"


def get_requires_for_build_wheel(config_settings=None):
    if not _native():
        return _setuptools.get_requires_for_build_wheel(config_settings)
    # setuptools runs setup.py to list what it needs: without mypyc, which is not there yet
    os.environ["ROBOX_NATIVE"] = "0"
    try:
        return [*_setuptools.get_requires_for_build_wheel(config_settings), MYPYC]
    finally:
        os.environ["ROBOX_NATIVE"] = "1"


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    if _native():
        print("robox: ROBOX_NATIVE is ignored for an editable install (compiled modules "
              "would hide later edits of the sources); building pure Python",
              file=sys.stderr)
        os.environ["ROBOX_NATIVE"] = "0"
    return _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)

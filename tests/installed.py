"""The installed package's own files, which the tests read where a user's install has
them (not from the source tree)."""

from pathlib import Path

import robox

PACKAGE_DATA = Path(robox.__file__).resolve().parent / "data"
EXAMPLE = PACKAGE_DATA / "example.gcode"

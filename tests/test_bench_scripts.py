"""The bench/ scripts run as the README shows them after either command: the first
installs the package without its test tools, so a bench imports no pytest, hypothesis
or pyfakefs (it may import this tree's plain helpers under tests/, which need none)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "bench").glob("*.py"))

BLOCKED = """
import runpy, sys
for name in ("pytest", "_pytest", "hypothesis", "pyfakefs"):
    sys.modules[name] = None  # importing it raises ImportError
sys.path.insert(0, sys.argv[1].rsplit("/", 1)[0])  # as `python bench/x.py` has it
runpy.run_path(sys.argv[1], run_name="imported")  # its imports, not its main()
"""


def test_every_bench_script_is_checked():
    assert {p.name for p in SCRIPTS} >= {"faults.py", "sdcard.py", "eeprom.py",
                                         "firmware_image.py", "send_job.py", "motion.py",
                                         "model.py", "translate.py"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_a_bench_script_imports_without_the_test_tools(script):
    done = subprocess.run([sys.executable, "-c", BLOCKED, str(script)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]

"""Start `robox-cli sim serve` as a real subprocess and stop it as a user would."""

import contextlib
import signal
import subprocess
import sys


@contextlib.contextmanager
def served(state, speed: float | None = None, options: tuple[str, ...] = ()):
    """Yields the pty path; on exit sends SIGTERM and checks a clean stop. `speed`: the
    clock paced to the wall's (1 = real time), else as fast as the work needs; `options`:
    more of `sim serve`'s."""
    pace = ["--speed", str(speed)] if speed is not None else []
    proc = subprocess.Popen([sys.executable, "-m", "robox.cli", "sim", "serve", "--state",
                             str(state), *pace, *options], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        yield proc.stdout.readline().strip()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "Traceback" not in err

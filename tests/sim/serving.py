"""Start `robox-cli sim serve` as a real subprocess and stop it as a user would."""

import contextlib
import os
import select
import signal
import subprocess
import sys
import time

from robox.formats.protocol import reply_length


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


def ask(server, frame: bytes) -> tuple[bytes, float]:
    """Write `frame` to an in-process PtyServer's pty as a host does and serve until its
    whole reply is there to read: the reply, and the wall seconds it took."""
    os.write(server.slave, frame)
    start, out = time.monotonic(), b""
    while reply_length(out) is None or len(out) < reply_length(out):
        assert time.monotonic() - start < 10, f"no reply to {frame[:1]!r}"
        server.serve_once(timeout=0.01)
        if select.select([server.slave], [], [], 0)[0]:
            out += os.read(server.slave, 4096)
    return out, time.monotonic() - start

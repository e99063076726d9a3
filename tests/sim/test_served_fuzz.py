"""Random bursts through a served printer's pseudo-terminal: it goes deaf where the
firmware model in this process does, and nowhere else.

The history is the one a hostile host found: bursts of 1-300 random bytes, each ended
with a line end, then 1,100 line ends, then a request for the firmware revision
(0xb4). Each burst reaches the printer as one transfer, through the pty as in process.
"""

import os
import random
import select
import time
import tty

import pytest

from robox.formats.protocol import reply_length
from robox.sim.printer import VirtualPrinter
from robox.sim.serve import HOST_QUIET_S, PtyServer

PROBE = b"\xb4"  # the firmware revision: answered 0xe4


def bursts(seed: int) -> list[bytes]:
    rng = random.Random(seed)
    out = [bytes(rng.randrange(256) for _ in range(rng.randint(1, 300))) + b"\r"
           for _ in range(30)]
    return [*out, b"\r" * 1100]


def in_process(seed: int) -> tuple[bytes, bool]:
    """The probe's answer (b"" for none) and whether the receiver went deaf."""
    printer = VirtualPrinter()
    printer.settle()
    usb = printer.usb
    for burst in bursts(seed):
        usb.host_write(burst)
        printer.run_until(None, 0.2)
        usb.host_read(1 << 20)
    usb.host_write(PROBE)
    printer.run_until(lambda: usb.reply_waiting >= 9, 1.0)
    answer = usb.host_read(1 << 20)
    deaf = printer.firmware.command.deaf
    printer.close()
    return answer, deaf


def through_the_pty(seed: int) -> tuple[bytes, bool, list[str]]:
    said: list[str] = []
    server = PtyServer(VirtualPrinter(), None, console=said.append)
    printer, usb = server.printer, server.printer.usb
    printer.settle()
    host = os.open(server.path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(host)
    out = b""

    # within less wall time than the server takes to count a silent host as gone: a
    # host that keeps writing (a probe a second, say) is never taken to have gone
    def serve_until(done, wall_s: float = HOST_QUIET_S / 2) -> None:
        nonlocal out
        end = time.monotonic() + wall_s
        while not done() and time.monotonic() < end:
            server.serve_once(timeout=0.001)
            while select.select([host], [], [], 0)[0]:
                out += os.read(host, 1 << 16)

    try:
        written = usb.bytes_in
        for burst in bursts(seed):
            os.write(host, burst)
            written += len(burst)
            serve_until(lambda w=written: usb.bytes_in == w)  # one read: one transfer
            # what the host wrote crosses and is taken (or, by a deaf receiver, left)
            # without the host saying more: nothing holds the clock while it is on
            # its way in
            later = printer.firmware.clock.now + 0.2

            def taken(t: float = later) -> bool:
                return not (usb.arriving or usb.received) or printer.firmware.clock.now >= t

            serve_until(taken)
            assert taken(), "the clock stood with the host's bytes on their way in"
        out = b""
        os.write(host, PROBE)
        serve_until(lambda: printer.firmware.command.deaf or (
            reply_length(out) is not None and len(out) >= reply_length(out)))
        return out, printer.firmware.command.deaf, said
    finally:
        os.close(host)
        server.close()
        printer.close()


@pytest.mark.parametrize("seed", range(8))
def test_random_bursts_leave_the_served_printer_as_they_leave_the_model(seed):
    answer, deaf = in_process(seed)
    served, served_deaf, said = through_the_pty(seed)
    assert served_deaf == deaf
    if deaf:
        assert served == b"" and any("no more input until reset" in m for m in said)
    else:
        assert answer[:1] == served[:1] == b"\xe4" and served == answer

"""100,000 random frames through the virtual printer, in process: not one exception.

There is no catch-all in the model's loop, so any exception a frame provokes reaches
this test. Frames are drawn (seeded, so a failure replays) from every command the
firmware knows, with well-formed, short, overlong and garbage parameters, G-code
lines full of absurd numbers, EEPROM writes of random fields, and raw bytes. Each
frame gets one pass of the loop and every hundredth a fifth of a second; a fresh
printer takes over every 2,000 frames so one deaf receiver cannot hide the rest.
"""

import random

from robox.firmware.command import FIXED, VARIABLE
from robox.sim.printer import VirtualPrinter

SEED = 14
FRAMES = 100_000
PER_PRINTER = 2_000

NUMBERS = ["nan", "-nan", "inf", "-inf", "1e39", "-1e39", "3.4e38", "1e10", "4294967296",
           "-2147483649", "0", "-0", "-1", "0x1p128", "1e-45", "2", "150", "0.5"]
WORDS = ["G0", "G1", "G4", "G28", "G36", "G37", "G38", "G39", "G90", "G91", "G92", "M84",
         "M104", "M106", "M109", "M120", "M121", "M122", "M140", "M170", "M190", "M201",
         "M202", "M906", "M907", "M909", "M92", "M526", "M527", "M114", "M119", "M503",
         "T0", "T1", "T2", "G1 B", "M113"]


def gcode_line(rng: random.Random) -> bytes:
    parts = [rng.choice(WORDS)]
    for _ in range(rng.randint(0, 4)):
        parts.append(rng.choice("XYZEDBFSPTIU") + rng.choice(NUMBERS))
    end = rng.choice(["\n", "\r", "\r\n", ";c\n", ""])
    return (" ".join(parts) + end).encode()


def field(rng: random.Random, size: int) -> bytes:
    kind = rng.random()
    if kind < 0.3:
        return bytes(rng.choice(b"0123456789abcdefABCDEF") for _ in range(size))
    if kind < 0.5:
        return rng.choice(NUMBERS).encode()[:size].ljust(size, b" ")
    if kind < 0.7:
        return bytes(rng.randrange(0x20, 0x7F) for _ in range(size))
    return bytes(rng.randrange(256) for _ in range(size))


def frame(rng: random.Random) -> bytes:
    kind = rng.random()
    if kind < 0.08:
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
    if kind < 0.2:
        return gcode_line(rng)  # Pronterface text (or junk after Robox mode)
    code = rng.choice(sorted(FIXED) + sorted(VARIABLE) + [0x80, 0x9F, 0xEE])
    if code in VARIABLE:
        header, at, digits = VARIABLE[code]
        body = gcode_line(rng) if code == 0x95 else field(rng, rng.randint(0, 60))
        count = len(body) if rng.random() < 0.8 else rng.randrange(1 << (4 * digits))
        head = bytearray(field(rng, header))
        head[at : at + digits] = f"{count:0{digits}x}".encode()
        return bytes([code]) + bytes(head) + body
    size = FIXED.get(code, 0)
    if code == 0x91:
        text = b"".join(gcode_line(rng) for _ in range(40))[:512].ljust(512, b"\n")
        return bytes([code]) + f"{rng.randrange(12):08x}".encode() + text
    if rng.random() < 0.1:
        size = rng.randint(0, size + 4)  # short or overlong
    return bytes([code]) + field(rng, size)


def test_a_hundred_thousand_random_frames_raise_nothing():
    rng = random.Random(SEED)
    printer = None
    for n in range(FRAMES):
        if n % PER_PRINTER == 0:
            printer = VirtualPrinter()
            printer.settle()
        data = frame(rng)
        try:
            printer.usb.host_write(data)
            printer.run_pass()
            if n % 100 == 99:
                printer.run_until(lambda: False, 0.2)
            while printer.usb.reply_waiting:
                printer.usb.host_read(4096)
        except Exception as exc:  # the report names the frame to replay
            raise AssertionError(f"frame {n} (seed {SEED}) {data[:80]!r} raised "
                                 f"{type(exc).__name__}: {exc}") from exc

"""Any byte sequence on the wire: no exception escapes, and the printer either answers the
next command or is, as the firmware would be, still collecting an incomplete one."""

import ctypes
import ctypes.util

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robox.firmware.command import FIXED, VARIABLE, get_hex
from robox.firmware.gcode import line_length
from robox.sim.printer import VirtualPrinter
from tests.firmware.wire import Wire

PRINTER = VirtualPrinter()
PRINTER.settle()

command_bytes = st.sampled_from([0x90, 0x91, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0xA0,
                                 0xA1, 0xA3, 0xB0, 0xB3, 0xC3, 0xF0, 0xFF, 0x80, 0xEE])
chunks = st.lists(st.one_of(st.binary(max_size=40), command_bytes.map(lambda b: bytes([b])),
                            st.sampled_from([b"0001", b"G1 X5\r", b"M105\r", b"\r\n", b"\x00"])),
                  max_size=30)


def waiting_for_more(wire: Wire) -> bool:
    """True when the receive buffer starts with a command (or line) still incomplete."""
    command = wire.fw.command
    buf = bytes(command.buffer)
    if command.deaf:
        return True
    if not command.robox_mode:
        return bool(buf) and line_length(buf) == 0
    if not buf or (buf[0] not in FIXED and buf[0] not in VARIABLE):
        return False
    if buf[0] in FIXED:
        return len(buf) < 1 + FIXED[buf[0]]
    header, at, digits = VARIABLE[buf[0]]
    if len(buf) < 1 + header:
        return True
    return len(buf) < 1 + header + (get_hex(buf[1 + at : 1 + at + digits]) & 0xFFFF)


def drain(wire: Wire) -> None:
    wire.printer.run_until(lambda: False, 0.2)
    while wire.usb.reply_waiting:
        wire.usb.host_read(4096)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chunks)
def test_random_robox_streams_never_break_the_model(parts):
    wire = Wire(PRINTER)
    wire.usb.host_write(b"\xb3")
    for part in parts:
        wire.usb.host_write(part)
        wire.printer.run_pass()
    drain(wire)
    wire.usb.host_write(b"\xb0")
    wire.printer.run_until(lambda: wire.usb.reply_waiting > 0, 0.5)
    if wire.usb.reply_waiting:
        drain(wire)
    else:
        assert waiting_for_more(wire)
    # start the next example from a freshly reset printer
    wire.fw.command.initialise()
    wire.fw.command.robox_mode = True
    wire.raw(b"\xc0")
    wire.raw(b"\xff")
    drain(wire)


@settings(max_examples=60, deadline=None)
# (7-bit bytes made as such: a filter on random bytes throws away nearly every part of
# more than a few bytes, and Hypothesis's health check fails the test at random)
@given(st.lists(st.binary(max_size=60).map(lambda raw: bytes(b & 0x7F for b in raw)),
                max_size=15))
def test_random_pronterface_text_is_answered_or_ignored(parts):
    wire = Wire(VirtualPrinter())
    for part in parts:
        wire.usb.host_write(part)
        wire.printer.run_pass()
    wire.usb.host_write(b"\nM115\n")
    # a line may heat, home or move filament first (M121 E: a minute to unload temperature,
    # then the unload's full travel), all in simulated time
    wire.printer.run_until(lambda: b"robox" in bytes(wire.usb._tx) or
                           wire.fw.command.robox_mode, 900)
    out = b""
    while wire.usb.reply_waiting:
        out += wire.usb.host_read(4096)
    if b"\0" in b"".join(parts):  # a NUL ends the C string: that line never completes
        assert out.endswith(b"ok\r\n") or wire.fw.command.buffer
    else:
        assert out.endswith(b"ok\r\n")


@settings(max_examples=3000, deadline=None)
@given(st.binary(max_size=12).map(lambda raw: bytes(b" \t\n\0+-xX0123456789abcdefABCDEFg"[
    b % 31] for b in raw)))
def test_hex_fields_read_as_the_c_librarys_strtoul_reads_them(field):
    """get_hex against strtoul(field, 16) itself: blanks, signs, 0x prefixes with and
    without a digit after them, NULs that end the field, junk (at most 12 characters,
    so no value reaches the 64 bits where strtoul would saturate)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.strtoul.restype = ctypes.c_ulong
    libc.strtoul.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]
    assert get_hex(field) == libc.strtoul(field, None, 16), field


@pytest.mark.parametrize("digits", [1, 4, 8, 14, 15, 16, 17, 20])
def test_long_hex_fields_keep_every_digit_to_64_bits(digits):
    """The digits past what adds up natively (15 and more) read as a whole number too,
    kept to its low 64 bits; from a bytearray as from bytes, and stopping at a NUL."""
    text = ("fedcba9876543210" * 2)[:digits].encode()
    expected = int(text, 16) & 0xFFFFFFFFFFFFFFFF
    assert get_hex(text) == expected
    assert get_hex(bytearray(b" 0x" + text.upper() + b"\0ff")) == expected
    assert get_hex(b"-" + text) == -int(text, 16) & 0xFFFFFFFFFFFFFFFF

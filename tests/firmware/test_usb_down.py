"""The firmware's receiver when the USB link goes down and comes back.

maintain_commands() (command.c) clears its receive and transmit counts on every pass
the link is not connected, and arms a read for the whole buffer once the link is
configured again; resetting the endpoints calls no transfer callback, so no USB error
is flagged. What was half received when the link went is gone: the next host's bytes
start a command of their own. The recorded sessions never pull the cable, so these
follow the source.
"""

from robox.hardware.usb import ReplyWaiting
from tests.firmware.wire import Wire, hexn

CUT_CHUNK = b"\x91" + hexn(0, 8) + b"x" * 100  # a chunk's header and a fifth of its data


def test_a_command_half_there_when_the_link_goes_takes_the_next_bytes_until_then(wire):
    wire.usb.host_write(CUT_CHUNK)
    wire.usb.host_write(b"\xb4")  # taken as the chunk's 101st byte: no report
    assert not wire.printer.run_until(ReplyWaiting(wire.usb), 1.0)


def test_the_link_going_down_drops_a_half_command_and_the_next_host_is_answered(wire):
    revision = wire.raw(b"\xb4")  # a whole 0xb4's report, before
    wire.usb.host_write(CUT_CHUNK)
    wire.printer.run_until(None, 0.05)  # all of it delivered and taken
    assert not wire.usb.arriving and not wire.usb.received
    wire.usb.disconnect()
    wire.printer.run_until(None, 0.05)
    wire.usb.connect()
    assert wire.raw(b"\xb4") == revision
    wire.ok(b"\xb3")  # no error: neither the dropped bytes nor the link's reset set any


def test_a_link_down_and_up_between_two_passes_is_seen_too(wire):
    revision = wire.raw(b"\xb4")
    wire.usb.host_write(CUT_CHUNK)
    wire.printer.run_until(None, 0.05)
    wire.usb.disconnect()
    wire.usb.connect()  # (no pass ran meanwhile: a cable is never out for less than one)
    assert wire.raw(b"\xb4") == revision
    wire.ok(b"\xb3")


def test_a_deaf_receiver_hears_again_once_the_link_has_been_down():
    w = Wire()
    w.printer.settle()
    w.usb.host_write(b"G" * 1100)  # Pronterface text with no line end fills the buffer
    assert w.printer.run_until(lambda: w.fw.command.deaf, 5.0)
    w.usb.host_write(b"\nM105\n")
    assert not w.printer.run_until(ReplyWaiting(w.usb), 1.0)  # deaf: nothing is read
    w.usb.disconnect()
    w.usb.connect()
    assert w.line(b"M105\n").endswith(b"ok\r\n")
    assert not w.fw.command.deaf

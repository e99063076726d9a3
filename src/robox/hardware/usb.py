"""The USB CDC link between a host and the printer, as the firmware and the host see it.

Bytes the host writes join a queue on the device's side of the bus. The firmware
reads with a transfer it arms (`arm`, with the room it has for bytes); at the end of
each loop pass (`frame`), if a read is armed and bytes are queued, up to one 64-byte
packet of them (no more than the room) is delivered as that transfer and the read is
disarmed until the firmware has taken them and arms it again. So a write made before
a pass is delivered at the end of it and taken in the next; an n-byte command needs
ceil(n/64) passes to arrive; a line that runs inside the command handler holds the
next packet back; and a firmware with no room left reads nothing more. (The recording
rig's USB, `../shared/conformance/README.md`; a PC's bulk transfers cross in the
same packets.)

Replies queue for the host in the order they were sent: the recordings of the real
firmware show every reply of a burst arriving (thirty Pronterface `ok`s from one
chunk of text, say) and USB_TX never set, so a reply is never clobbered here. A
reply counts as "in flight" until the host has read it (a reset waits for that). A
disconnect drops everything in both directions, and is counted (`downs`): the firmware
drops what its receiver held when it sees the link has been down (Command.maintain).
"""

from __future__ import annotations

from typing import Final

from robox.errors import RoboxError
from robox.hardware.clock import PassCondition

PACKET_SIZE: Final = 64


class LinkDown(RoboxError):
    """The USB link is disconnected."""


class UsbLink:
    def __init__(self) -> None:
        self.connected = True
        # (bytes, each taken from by a slice and replaced: compiled, slicing and joining
        # bytes are native, where a bytearray's slice and deletion are generic calls)
        self._rx = b""  # host -> device, delivered, not yet taken by the firmware
        self._host = b""  # host -> device, written, not yet delivered
        self.armed = True  # the firmware has a read armed
        self.room = 1 << 30  # how many bytes that read may take
        self._tx = b""  # replies the host has not read yet
        self.replies = 0
        self.bytes_in = 0
        self.bytes_out = 0
        self.downs = 0  # disconnects so far

    # ----------------------------------------------------------- host side
    def host_write(self, data: bytes) -> None:
        if not self.connected:
            raise LinkDown("the printer is not connected")
        self._host += data
        self.bytes_in += len(data)

    def host_read(self, limit: int = PACKET_SIZE) -> bytes:
        if not self.connected:
            raise LinkDown("the printer is not connected")
        out = self._tx[:limit]
        self._tx = self._tx[limit:]
        return out

    @property
    def reply_waiting(self) -> int:
        return len(self._tx)

    def disconnect(self) -> None:
        if self.connected:
            self.downs += 1
        self.connected = False
        self._rx = self._host = self._tx = b""

    def connect(self) -> None:
        self.connected = True

    # --------------------------------------------------------- device side
    def arm(self, room: int) -> None:
        """The firmware arms a read for up to `room` bytes."""
        self.armed = True
        self.room = room

    def frame(self) -> None:
        """The end of a loop pass: a packet of the host's bytes to an armed read."""
        if not self.armed or not len(self._host):  # (a length: compiled, no generic test)
            return
        # (two-way ifs, not min() of three: compiled, native integers)
        n = len(self._host)
        if self.room < n:
            n = self.room
        if n > PACKET_SIZE:
            n = PACKET_SIZE
        if n <= 0:
            return
        self._rx += self._host[:n]
        self._host = self._host[n:]
        self.armed = False

    def frames_within(self, inert: int) -> int:
        """How many of the coming frames deliver only bytes among the first `inert` of
        those on their way (delivered ones first), the read armed again each time with
        the room left: a look ahead that delivers nothing."""
        got = len(self._rx)
        left = len(self._host)
        room = self.room - got
        k = 0
        while left > 0 and room > 0:
            n = left if left < room else room
            if n > PACKET_SIZE:
                n = PACKET_SIZE
            if got + n > inert:
                break
            got += n
            left -= n
            room -= n
            k += 1
        return k

    def peek(self, n: int) -> bytes:
        """The first `n` bytes on their way (delivered ones first), left where they are."""
        out = self._rx[:n]
        return out + self._host[:n - len(out)] if len(out) < n else out

    @property
    def delivering(self) -> bool:
        """Bytes from the host are queued and the firmware's read can take some."""
        return len(self._host) > 0 and self.armed and self.room > 0

    @property
    def arriving(self) -> bool:
        """Bytes from the host are queued, not yet delivered."""
        return len(self._host) > 0

    @property
    def received(self) -> int:
        return len(self._rx)

    def device_take(self, limit: int) -> bytes:
        out = self._rx[:limit]
        self._rx = self._rx[limit:]
        return out

    @property
    def in_flight(self) -> bool:
        return bool(self._tx)

    def device_send(self, reply: bytes) -> bool:
        """Queue a reply for the host (dropped while disconnected)."""
        if not self.connected:
            return True
        self._tx += reply
        self.replies += 1
        self.bytes_out += len(reply)
        return True


class ReplyWaiting(PassCondition):
    """A condition for Firmware.run_until: a reply waits for the host (with `or_gone`, or
    the link is gone). A compiled object, where a lambda would run interpreted after
    every pass."""

    def __init__(self, link: UsbLink, or_gone: bool = False):
        self.link = link
        self.or_gone = or_gone

    def holds(self) -> bool:
        link = self.link
        return link.reply_waiting > 0 or (self.or_gone and not link.connected)

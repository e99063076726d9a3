"""The USB CDC link between a host and the printer, as the firmware and the host see it.

Bytes the host writes wait in the device's receive endpoint until the firmware
takes them. Replies queue for the host in the order they were sent: the
recordings of the real firmware show every reply of a burst arriving (thirty
Pronterface `ok`s from one chunk of text, say) and USB_TX never set, so a
reply is never clobbered here. A reply counts as "in flight" until the host
has read it (a reset waits for that). A disconnect drops everything in both
directions.
"""

from __future__ import annotations

from collections import deque

from robox.errors import RoboxError

PACKET_SIZE = 64


class LinkDown(RoboxError):
    """The USB link is disconnected."""


class UsbLink:
    def __init__(self) -> None:
        self.connected = True
        self._rx = bytearray()  # host -> device, arrived, not yet taken by the firmware
        self._transfers: deque[list] = deque()  # [data, packets still to cross]
        self._tx = bytearray()  # replies the host has not read yet
        self.replies = 0
        self.bytes_in = 0
        self.bytes_out = 0

    # ----------------------------------------------------------- host side
    def host_write(self, data: bytes) -> None:
        if not self.connected:
            raise LinkDown("the printer is not connected")
        if data:
            self._transfers.append([bytes(data), -(-len(data) // PACKET_SIZE)])
        self.bytes_in += len(data)

    def host_read(self, limit: int = PACKET_SIZE) -> bytes:
        if not self.connected:
            raise LinkDown("the printer is not connected")
        out = bytes(self._tx[:limit])
        del self._tx[:limit]
        return out

    @property
    def reply_waiting(self) -> int:
        return len(self._tx)

    def disconnect(self) -> None:
        self.connected = False
        self._rx.clear()
        self._transfers.clear()
        self._tx.clear()

    def connect(self) -> None:
        self.connected = True

    # --------------------------------------------------------- device side
    def frame(self) -> None:
        """One bus frame: the next packet of the host's oldest transfer crosses; a
        transfer whose last packet is in reaches the receive endpoint whole."""
        if not self._transfers:
            return
        head = self._transfers[0]
        head[1] -= 1
        if head[1] <= 0:
            self._rx += head[0]
            self._transfers.popleft()

    def frames_to_land(self) -> int:
        """How many more frames until the oldest transfer from the host has landed whole
        (0: none is crossing)."""
        return max(1, self._transfers[0][1]) if self._transfers else 0

    @property
    def arriving(self) -> bool:
        """A transfer from the host is still crossing the bus."""
        return bool(self._transfers)

    @property
    def received(self) -> int:
        return len(self._rx)

    def device_take(self, limit: int) -> bytes:
        out = bytes(self._rx[:limit])
        del self._rx[:limit]
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

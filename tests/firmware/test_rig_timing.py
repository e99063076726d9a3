"""The recording rig's timing (../shared/conformance/README.md, "The recording rig's
timing"), kept by the simulated hardware: whole recorded sessions replayed by a host that
acts as the rig's host did, every reply compared with the real firmware's bytes and
every write and every byte the firmware sent with the millisecond the rig gave it.

The sessions (`data/rig_sessions.json`, from the traces and their timed replays): mixed
137 and 592 (Pronterface filament moves whose ends the host sees; text frames that
arrive a packet at a time) and mechanics 90 and 170 (homing, tool changes and moves read
part-way). Each rule has a test here that breaks the session it decides.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from robox.firmware.motion import IDLE_PERIOD, Motion
from robox.hardware.machine import VALVE_REST_STEPS
from robox.sim.printer import VirtualPrinter

SESSIONS = json.loads((Path(__file__).parent / "data" / "rig_sessions.json").read_text())
REPLY_WAIT_S = 0.3  # the rig's host waits this long for a reply
SETTLE_S = 2.0  # and starts this long after power-up

#: the status report's and M105's measured temperatures: the thermal physics differ
TEMPERATURES = [(41, 49), (66, 74), (91, 99), (116, 124)]


def masked(reply: bytes) -> bytes:
    if reply[:1] == b"\xe1" and len(reply) >= 124:
        out = bytearray(reply)
        for a, b in TEMPERATURES:
            out[a:b] = b"#" * (b - a)
        return bytes(out)
    if reply.startswith(b"S:"):  # M105's text: temperatures, duties, the mains marker
        reply = re.sub(rb"(S|T|B|A):-?[0-9]+", rb"\1:#", reply)
        return re.sub(rb"[@*$^][0-9]+", rb"##", reply)
    return reply


class RigHost:
    """A host that keeps the rig's rules: before each pass it looks; a wait for a reply
    ends once every byte it wrote has been delivered and taken, and something has been
    written since it last read (or 0.3 s of printer time ran out); it then reads it all
    and writes the next step at once."""

    def __init__(self, printer: VirtualPrinter):
        self.p = printer
        self.usb = printer.usb
        self.sent = 0
        self.events: list[list[int]] = []

    def _ms(self) -> int:
        return round(self.p.firmware.clock.now * 1000)

    def _look(self) -> bool:
        """After each pass: what the firmware sent in it, booked at its millisecond."""
        out = self.usb.bytes_out
        if out != self.sent:
            ms = self._ms()
            if self.events and self.events[-1][:2] == ["send", ms]:
                self.events[-1][2] += out - self.sent
            else:
                self.events.append(["send", ms, out - self.sent])
            self.sent = out
        return False

    def _answered(self) -> bool:
        self._look()
        usb = self.usb
        return not usb.arriving and usb.received == 0 and usb.reply_waiting > 0

    def _read_all(self) -> bytes:
        out = b""
        while self.usb.reply_waiting:
            out += self.usb.host_read(64)
        return out

    def run(self, steps: list) -> list[bytes]:
        self.p.run_until(self._look, SETTLE_S)
        replies = []
        for n, (kind, value) in enumerate(steps):
            if kind == "wait":
                self.p.run_until(self._look, float(value))
            else:
                self.events.append(["write", n, self._ms()])
                self.usb.host_write(bytes.fromhex(value))
                self.p.run_until(self._answered, REPLY_WAIT_S)
            replies.append(self._read_all())
        return replies


def recorded_events(session: dict) -> list[list[int]]:
    """The timed replay's events, the bytes sent in one millisecond added up."""
    out: list[list[int]] = []
    for kind, a, b in session["events"]:
        if kind == "send" and out and out[-1][:2] == ["send", a]:
            out[-1][2] += b
        else:
            out.append([kind, a, b])
    return out


def replay(name: str, before=None) -> tuple[list[bytes], list[list[int]], list[bytes]]:
    session = SESSIONS[name]
    printer = VirtualPrinter(card_blocks=session["blocks"])
    if before is not None:
        before(printer)
    host = RigHost(printer)
    replies = host.run(session["steps"])
    real = [bytes.fromhex(r) for r in session["replies"]]
    return [masked(r) for r in replies], host.events, [masked(r) for r in real]


@pytest.mark.parametrize("name", sorted(SESSIONS))
def test_a_session_keeps_the_rigs_time_to_the_millisecond(name):
    replies, events, real = replay(name)
    assert replies == real
    assert events == recorded_events(SESSIONS[name])


def test_the_first_write_after_the_settle_is_a_pass_late():
    # The clock adds 1 ms per pass as a double: 2,000 passes leave it a hair short of 2 s,
    # so the host's 2 s wait ends a pass later, and the rig's first write is at 2001 ms.
    assert SESSIONS["mixed 137"]["events"][0] == ["write", 0, 2001]
    printer = VirtualPrinter(card_blocks=16384)
    printer.run_until(lambda: False, SETTLE_S)
    assert round(printer.firmware.clock.now * 1000) == 2001
    assert printer.firmware.clock.now == sum([0.001] * 2001)


def test_text_frames_arrive_a_packet_a_pass():
    # Session 592, step 5: a 521-byte chunk frame written into an unfinished text line
    # is text. Its packets arrive one a pass and each is answered as it comes: the first
    # "ok"s two passes after the write, the last ones 130 ms later, once the filament
    # moves have made room in the queue.
    replies, events, real = replay("mixed 592")
    step5 = next(e for e in events if e[0] == "write" and e[1] == 5)
    sends = [e for e in events if e[0] == "send" and step5[2] < e[1] <= 2443]
    assert sends[0][1] == step5[2] + 2
    assert sends[0][2] == len(b"Xdelta:0.000000\r\nok\r\n") + 3 * 4
    assert sum(e[2] for e in sends) == len(real[5]) == 237
    assert replies[5] == real[5]


def test_the_valve_rests_on_the_nozzle_0_side_at_power_up():
    # Mechanics 170 reads X part-way through a move that follows a tool change: with the
    # valve at its switch instead, the change ends sooner and the move is a segment on.
    assert VALVE_REST_STEPS == 1750
    replies, _, real = replay("mechanics 170")
    assert replies == real

    def at_switch(printer):
        printer.hw.machine.b = 0

    replies, _, real = replay("mechanics 170", at_switch)
    assert replies != real


def test_the_step_timer_starts_2_ms_after_power_up():
    # The idle step interrupt's phase decides when a block queued while idle starts:
    # with the first compare one period after power-up, not 2 ms later, session 90's
    # homing starts at another interrupt and a later move's position read part-way differs.
    def timer_at_power_up(printer):
        motion: Motion = printer.firmware.motion
        motion.next_tick = IDLE_PERIOD
        motion.last_tick = 0

    replies, _, real = replay("mechanics 90")
    assert replies == real
    replies, _, real = replay("mechanics 90", timer_at_power_up)
    assert [i for i, (a, b) in enumerate(zip(replies, real, strict=True)) if a != b] == [23]

"""The command object: the USB receive buffer, both modes, every command and report.

It follows the firmware's `maintain_commands()`. Bytes from the USB link are
appended to a 1024-byte receive buffer, then everything complete in it is
handled, oldest first; an incomplete command or line stays until the rest
arrives. The mode is decided where a command starts: a byte >= 0x80 there
switches to Robox mode for good. Within a Pronterface line, bytes >= 0x80 are
just text.

What follows from the firmware's handling, and a host can see:

- Robox mode: a command waits until all its parameter bytes are there,
  whatever they are (so a count in a header larger than the buffer leaves
  the printer waiting for ever); an unknown code sets BAD_COMMAND and is
  dropped alone. Hex fields are read like C's `strtoul(.., 16)`.
- Pronterface mode: each complete line (even an empty one) runs at once and
  is answered with its response and `ok`; a NUL byte ends the text, so a line
  holding one never completes.
- A full buffer with nothing complete in it is never read from again: the
  printer is deaf until reset (`deaf` is set and an event recorded), or until the
  USB link goes down and comes back.
- Once the link has been down (a cable pulled, a host's port reset), whatever the
  buffer held is dropped and the read armed afresh for the whole buffer: a command
  that was half there when the link went does not swallow the next host's bytes.
  (maintain_commands() clears its counts on every pass the link is not connected,
  and arms a new read when it is configured again; the endpoints' reset calls no
  transfer callback, so no error is flagged.) A line running here runs to its end
  first, as it runs inside that call.
- A line that runs here (a Pronterface line, or a reporting 0x95) runs to its
  end before anything else is read, and the job engine waits meanwhile, as on
  the printer where the line runs inside this call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Final

from robox.firmware.gcode import Wait, Waits, heater_looked, is_reporting
from robox.formats.eeprom import EepromIndex
from robox.formats.float8 import skip_blanks
from robox.formats.protocol import PAUSE_MASK, PAUSE_MASK_CONNECTED, ErrorBit
from robox.formats.sdcard import ID_SIZE
from robox.packed import i64

if TYPE_CHECKING:
    from robox.firmware.error_flags import ErrorFlags
    from robox.firmware.main import Firmware

RECEIVE_BUFFER: Final = 1024
HOST_CONNECTED_S: Final = 5.0

MEMORY_SIZE: Final = 0x10000

# Commands with no parameters, and the fixed parameter length of the others.
FIXED: Final = {
    0x8F: 16, 0x90: 16, 0x97: 16, 0x91: 8 + 512, 0x93: 0, 0x94: 16, 0x96: 0, 0x98: 1,
    0xA1: 0, 0xA3: 0, 0xA5: 0, 0xB0: 0, 0xB2: 0, 0xB3: 0, 0xB4: 0, 0xB6: 0, 0xBB: 0,
    0xC0: 0, 0xC1: 256, 0xC2: 6, 0xC3: 56, 0xC4: 8, 0xC5: 6, 0xC6: 8, 0xC7: 8, 0xC8: 16,
    0xC9: 16, 0xCA: 1, 0xF8: 0, 0xF9: 0, 0xFA: 0, 0xFB: 0, 0xFC: 0, 0xFD: 0, 0xFE: 0, 0xFF: 0,
}
# Commands whose header carries a count: (header length, count offset, count digits)
VARIABLE: Final = {0x92: (12, 8, 4), 0x95: (4, 0, 4), 0xA0: (4, 2, 2), 0xA2: (4, 2, 2),
                   0xA4: (4, 2, 2), 0xF0: (12, 8, 4)}


UNKNOWN_CODE: Final = -1
HEADER_INCOMPLETE: Final = -2
_COUNTED: Final = -3
# each code's entry in FIXED, or UNKNOWN_CODE, or _COUNTED (in VARIABLE), by the code
# (a tuple indexed natively, compiled: where a dict is looked up twice with a boxed key)
_LENGTHS: Final = tuple(FIXED.get(c, _COUNTED if c in VARIABLE else UNKNOWN_CODE)
                        for c in range(256))


def parameter_length(buf: bytes) -> int:
    """The parameter bytes of the Robox command whose code starts `buf`: fixed, or its
    header's count; UNKNOWN_CODE for a code the firmware does not know, HEADER_INCOMPLETE
    while a counted header is not all there."""
    code = buf[0]
    fixed: int = _LENGTHS[code]
    if fixed != _COUNTED:
        return fixed
    header, at, digits = VARIABLE[code]
    if len(buf) < 1 + header:
        return HEADER_INCOMPLETE
    return header + (get_hex(buf[1 + at : 1 + at + digits]) & 0xFFFF)


def _no_reply(response: bytes) -> None:
    """Where a line's response goes before any line has run."""


def get_hex(field: bytes | bytearray) -> int:
    """The firmware's get_hex: strtoul(field, 16) over the field as a C string."""
    # (bytes from here, the positions native integers: compiled, a union's items are
    # generic lookups, and splitting at the NUL made a list and a copy)
    text: bytes = field if isinstance(field, bytes) else bytes(field)
    n: i64 = len(text)
    k: i64
    for k in range(n):  # the C string ends at its first NUL
        if text[k] == 0:
            n = k
            break
    i = skip_blanks(text, 0)  # (it stops at the NUL, if not before)
    negative = i < n and text[i] == 45  # -
    if i < n and (text[i] == 43 or text[i] == 45):
        i += 1
    if i + 2 < n and text[i] == 48 and text[i + 1] | 0x20 == 120 and _hex_digit(text[i + 2]):
        i += 2  # 0x or 0X, taken only before a digit
    j: i64 = i
    while j < n and _hex_digit(text[j]):
        j += 1
    value: int
    if j - i <= 15:  # (below 2**60: added up natively)
        whole: i64 = 0
        for k in range(i, j):
            c = text[k] | 0x20
            whole = whole * 16 + (c - 48 if c <= 57 else c - 87)
        value = whole
    else:
        value = int(text[i:j], 16)
    return (-value if negative else value) & 0xFFFFFFFFFFFFFFFF


def _hex_digit(c: int) -> bool:
    return 48 <= c <= 57 or 97 <= (c | 0x20) <= 102  # 0-9, a-f, A-F


def put_hex(value: int, digits: int) -> bytes:
    # (printf-style on bytes: compiled, no format-string parsing and no encoding)
    return b"%0*x" % (digits, value & ((1 << 4 * digits) - 1))


class Command:
    """Robox and Pronterface protocols on the USB link."""

    # (scalars set at power-up, in initialise; the defaults only spare the compiled
    # code a test at every read of whether the attribute was ever set)
    buffer: bytes = b""
    robox_mode: bool = False
    last_ack_report: float = 0.0
    deaf: bool = False
    heater_looked: bool = False

    def __init__(self, firmware: Firmware):
        self.fw = firmware

    def initialise(self) -> None:
        # (bytes, sliced and replaced: compiled, native, where a bytearray's are generic)
        self.buffer = b""
        self.robox_mode = False
        self.last_ack_report = self.fw.clock.now
        self.memory = bytearray(MEMORY_SIZE)  # the simulated address space of 0xf0
        # reset or reprogram once the reply has left
        self.pending_after_reply: Callable[[], object] | None = None
        self.line: Waits | None = None  # a line running inside this object
        self.line_reply: Callable[[bytes], None] = _no_reply  # how its response is sent
        self.waiting: Wait | None = None
        # whether the heater that line waits on has been looked at since it began to wait
        # (as Job.heater_looked)
        self.heater_looked = False
        self.deaf = False
        link = self.fw.hw.usb
        self.downs_seen = link.downs  # the link's disconnects this object has seen
        link.arm(RECEIVE_BUFFER)  # the read armed afresh, for the whole buffer

    # ------------------------------------------------------------ errors
    @property
    def errors(self) -> ErrorFlags:
        return self.fw.errors

    def host_connected(self) -> bool:
        return self.fw.hw.usb.connected and \
            self.fw.clock.now - self.last_ack_report < HOST_CONNECTED_S

    def is_error(self) -> bool:
        bits = self.errors.bits
        if not bits:
            return False  # (the job asks at every line: compiled, no 64-bit mask taken)
        mask = PAUSE_MASK_CONNECTED if self.host_connected() else PAUSE_MASK
        return bool(bits & mask)

    # ---------------------------------------------------------- the loop
    def maintain(self) -> None:
        link = self.fw.hw.usb
        if self.pending_after_reply is not None and not link.in_flight:
            action, self.pending_after_reply = self.pending_after_reply, None
            action()
            return
        if self.line is not None:
            if not self._drive_line():
                return
            self._handle()
            self._arm(link)
            return
        if link.downs != self.downs_seen:  # the link has been down since the last look
            self.downs_seen = link.downs
            self.buffer = b""
            self.deaf = False
            link.arm(RECEIVE_BUFFER)
        if self.deaf or not link.received:
            return
        self.buffer += link.device_take(RECEIVE_BUFFER - len(self.buffer))
        self._handle()
        self._arm(link)

    def _arm(self, link) -> None:
        """The read armed again once what came is handled (not while a line runs here:
        it holds the next packet back), for the room the buffer has left."""
        if self.line is None:
            link.arm(RECEIVE_BUFFER - len(self.buffer))

    def take_inert(self) -> None:
        """Take what the link delivered when it cannot complete anything (inert_bytes
        said so): into the buffer, and the read armed again, as maintain() would."""
        link = self.fw.hw.usb
        self.buffer += link.device_take(RECEIVE_BUFFER - len(self.buffer))
        link.arm(RECEIVE_BUFFER - len(self.buffer))

    def inert_bytes(self) -> int:
        """How many of the bytes on their way from the host (delivered first, then
        queued) this object would only add to its buffer: those before the byte that
        completes the Robox command at its head, and short of filling the buffer. 0 when
        the next byte may act: a text line (any byte may end it), a line running here,
        an unknown code, a header not yet whole."""
        if self.deaf or self.line is not None or self.pending_after_reply is not None \
                or self.fw.hw.usb.downs != self.downs_seen:  # (the next pass drops it all)
            return 0
        have = len(self.buffer)
        buf = self.buffer
        if have == 0:
            head = self.fw.hw.usb.peek(13)
            if not head or head[0] < 0x80:
                return 0
        elif not self.robox_mode:
            return 0
        else:
            head = buf[:13]
            if len(head) < 13:
                head += self.fw.hw.usb.peek(13 - len(head))
        n = parameter_length(head)
        if n < 0:
            return 0
        return max(0, min(n, RECEIVE_BUFFER - 1) - have)

    def busy_line(self) -> bool:
        """True while a line runs here (the job engine waits, as on the printer)."""
        return self.line is not None

    def _handle(self) -> None:
        """Handle everything complete in the buffer, oldest first."""
        while self.buffer and self.line is None:
            if self.buffer[0] >= 0x80:
                self.robox_mode = True
            n = self._robox() if self.robox_mode else self._pronterface()
            if n == 0:
                break
            self.buffer = self.buffer[n:]
        if len(self.buffer) >= RECEIVE_BUFFER and self.line is None and not self.deaf:
            self.deaf = True
            self.fw.events.append(("deaf", "1024 bytes with no complete command or line: "
                                   "the printer reads no more input until reset"))

    def _run_line(self, text: bytes, reply) -> None:
        self.line = self.fw.job.run_now(text)
        self.line_reply = reply
        self._drive_line()

    def _drive_line(self) -> bool:
        """One step of the line under way; True once it has finished (and answered)."""
        try:
            line = self.line
            assert line is not None
            before = self.waiting
            waiting = next(line)
            self.waiting = waiting
            self.heater_looked = heater_looked(before, waiting)
            return False
        except StopIteration as done:
            self.line = None
            self.waiting = None
            self.line_reply(done.value or b"")
            return True

    def send(self, reply: bytes) -> None:
        if not self.fw.hw.usb.device_send(reply):
            self.errors.set(ErrorBit.USB_TX)

    def after_reply(self, action: Callable[[], object]) -> None:
        """Run `action` once the reply now in flight has been read by the host."""
        self.pending_after_reply = action

    # ------------------------------------------------------ Pronterface
    def _pronterface(self) -> int:
        from robox.firmware.gcode import line_length

        n = line_length(self.buffer)
        if n:
            self._run_line(self.buffer[:n], self._send_text)
        return n

    def _send_text(self, response: bytes) -> None:
        if response:
            self.send(response)

    # ---------------------------------------------------------- Robox
    def _robox(self) -> int:
        buf = self.buffer
        code = buf[0]
        length = parameter_length(buf)
        if length == UNKNOWN_CODE:
            self.errors.set(ErrorBit.BAD_COMMAND)
            return 1
        if length == HEADER_INCOMPLETE or len(buf) < 1 + length:
            return 0
        params = buf[1 : 1 + length]
        self._dispatch(code, params)
        return 1 + length

    def ack(self) -> None:
        self.last_ack_report = self.fw.clock.now
        self.send(b"\xe3" + self.errors.report())

    def _dispatch(self, code: int, p: bytes) -> None:
        fw = self.fw
        fs = fw.file_system
        if code in (0x90, 0x97):
            fs.start_write_file(p[:16], code == 0x97)
        elif code == 0x91:
            fs.write_chunk(get_hex(p[:8]), p[8:520])
        elif code == 0x92:
            count = get_hex(p[8:12]) & 0xFFFF
            fs.end_write_file(get_hex(p[:8]), p[12 : 12 + min(512, count)])
        elif code == 0x93:
            file_id, chunk = fs.send_file_report()
            self.send(b"\xe9" + file_id + put_hex(chunk, 8))
            return
        elif code == 0x94:
            fw.job.run_job(p[:16])
        elif code == 0x95:
            text = p[4:]
            if not is_reporting(text):
                fw.job.execute_gcode(text)
                self.send(b"\xe70000")
            else:
                self._run_line(text, self._send_gcode_report)
            return
        elif code == 0x96:
            files = fs.file_list()
            self.send(b"\xe0" + put_hex(len(files), 2) + b"".join(files))
            return
        elif code == 0x98:
            fw.job.pause_resume(p[:1])
        elif code in (0xA0, 0xA2, 0xA4):
            index = EepromIndex((code - 0xA0) // 2)
            address, count = get_hex(p[:2]) & 0xFFFF, get_hex(p[2:4]) & 0xFFFF
            fw.eeproms.host_write(index, address, p[4 : 4 + count])
        elif code in (0xA1, 0xA3, 0xA5):
            index = EepromIndex((code - 0xA1) // 2)
            self.send(bytes([(0xE2, 0xE6, 0xE8)[index]]) + fw.eeproms.host_read(index))
            return
        elif code == 0xB0:
            self.send(self.status_report())
            return
        elif code == 0xB2:
            self.send(b"\xe5" + bytes(b & 0x7F for b in fw.parameters.unique_id()))
            return
        elif code == 0xB3:
            pass
        elif code == 0xB4:
            self.send(b"\xe4" + fw.revision.encode("ascii")[:8].ljust(8, b"\0"))
            return
        elif code == 0xB6:
            self.send(b"\xea" + fw.parameters.hours_text())
            return
        elif code == 0xBB:
            self.send(b"\xeb" + (b"1" if fw.hw.card.present else b"0"))
            return
        elif code == 0xC0:
            self.errors.clear()
        elif code == 0xC1:
            fw.parameters.write_unique_id(p)
        elif code in (0xC2, 0xC5):
            colour = (get_hex(p[0:2]) & 0xFF, get_hex(p[2:4]) & 0xFF, get_hex(p[4:6]) & 0xFF)
            fw.user_interface.set_led(ambient=code == 0xC2, colour=colour)
        elif code == 0xC3:
            fw.heaters.set_targets(p)
        elif code in (0xC4, 0xC7):
            fw.position.set_feed_rate_multiplier("D" if code == 0xC4 else "E", p[:8])
        elif code == 0xC6:
            fw.parameters.write_hours(p[:8])
        elif code in (0xC8, 0xC9):
            fw.position.set_filament_info("E" if code == 0xC8 else "D", p[:16])
        elif code == 0xCA:
            fw.heaters.set_head_power(p[:1] == b"1")
        elif code == 0xF0:
            self.send(b"\xf0" + self._memory(p))
            return
        elif code in (0xF8, 0xF9, 0xFA):
            fw.eeproms.format(EepromIndex(code - 0xF8))
        elif code == 0xFB:
            self.send(b"\xfb" + fw.debug_text().encode("ascii", "replace")[:256].ljust(256, b"\0"))
            return
        elif code == 0xFC:
            self.send(b"\xef" + fw.board_test_text().encode("ascii", "replace")[:256]
                      .ljust(256, b"\0"))
            return
        elif code == 0xFD:
            self.ack()
            self.after_reply(fw.request_reset)
            return
        elif code == 0xFE:
            fs.format()
        elif code == 0xFF:
            fw.job.abort()
        elif code == 0x8F:
            image = fw.reprogram.check(p[:16])
            self.ack()
            if image is not None:
                self.after_reply(lambda: fw.reprogram.flash(image))
            return
        self.ack()

    def _send_gcode_report(self, response: bytes) -> None:
        response = response.split(b"\0", 1)[0]
        self.send(b"\xe7" + put_hex(len(response), 4) + response)

    def _memory(self, p: bytes) -> bytes:
        address = get_hex(p[:8]) % MEMORY_SIZE
        count = (get_hex(p[8:12]) & 0xFFFF) // 2
        digits = p[12:]
        for i in range(count):
            self.memory[(address + i) % MEMORY_SIZE] = get_hex(digits[2 * i : 2 * i + 2]) & 0xFF
        data = bytes(self.memory[(address + i) % MEMORY_SIZE] for i in range(128))
        return data.hex().encode()

    # ------------------------------------------------------- status 0xe1
    def status_report(self) -> bytes:
        fw = self.fw
        machine = fw.hw.machine
        # (the parts joined once: compiled, one allocation, where a buffer grows 15 times)
        out = b"".join([
            b"\xe1",
            fw.file_system.reading or bytes(ID_SIZE),
            fw.job.state_text(),
            fw.motion.switch_states(),
            b"0" if machine.button_pressed else b"1",  # the raw pin: high when released
            fw.motion.index_and_z_top(),
            b"1" if fw.position.extruder_present("E") else b"0",
            b"1" if fw.position.extruder_present("D") else b"0",
            fw.heaters.report_block(),
            fw.eeproms.status_characters(),
            b"1" if fw.hw.card.present else b"0",
            fw.position.position_report(),
            fw.position.filament_report(),
            b"1" if machine.head_power else b"0",
            b"%d" % (machine.hardware_revision % 10),
        ])
        assert len(out) == 222, len(out)
        return out

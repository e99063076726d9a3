"""The command object: the USB receive buffer, both modes, every command and report.

Bytes move from the USB link into a 1024-byte receive buffer as space allows.
In Pronterface-compatible mode (the state after power-up) the buffer holds
G-code lines; the first byte >= 0x80 where a line may start switches to Robox
mode for good. In Robox mode the buffer starts with a command byte; a command
whose parameters have not all arrived waits for them.

Choices where protocol.md is silent (documented in docs/firmware-model.md):
- a byte >= 0x80 among a command's parameters abandons that command (USB_RX)
  and parsing restarts at that byte, since parameters are always ASCII;
- hex fields read non-hex characters as 0;
- in Pronterface mode, a leading `N<line>` and a trailing `*<checksum>` (what
  Printrun and OctoPrint add) are removed before the line is executed, and a
  line that is not a reporting code is answered `ok` once it has run (so M400
  or M109 answer when done), which is what those hosts count on.
"""

from __future__ import annotations

from robox.formats import float8
from robox.formats.protocol import ErrorBit
from robox.formats.sdcard import ID_SIZE

RECEIVE_BUFFER = 1024
HOST_CONNECTED_S = 5.0

NEVER_PAUSE = {ErrorBit.B_POSITION_WARNING, ErrorBit.B_POSITION_LOST,
               ErrorBit.POWEROFF_WHILST_HOT, ErrorBit.E_NO_FILAMENT, ErrorBit.D_NO_FILAMENT}
NO_PAUSE_WHILE_CONNECTED = {ErrorBit.NOZZLE_FLUSH_NEEDED, ErrorBit.E_FILAMENT_SLIP,
                            ErrorBit.D_FILAMENT_SLIP}
PAUSE_MASK = sum(1 << bit for bit in ErrorBit if bit not in NEVER_PAUSE)
PAUSE_MASK_CONNECTED = sum(1 << bit for bit in ErrorBit
                           if bit not in NEVER_PAUSE | NO_PAUSE_WHILE_CONNECTED)

# Fixed parameter lengths; None: variable (the header says how many bytes follow).
FIXED = {
    0x8F: 16, 0x90: 16, 0x97: 16, 0x91: 8 + 512, 0x93: 0, 0x94: 16, 0x96: 0, 0x98: 1,
    0xA1: 0, 0xA3: 0, 0xA5: 0, 0xB0: 0, 0xB2: 0, 0xB3: 0, 0xB4: 0, 0xB6: 0, 0xBB: 0,
    0xC0: 0, 0xC1: 256, 0xC2: 6, 0xC3: 56, 0xC4: 8, 0xC5: 6, 0xC6: 8, 0xC7: 8, 0xC8: 16,
    0xC9: 16, 0xCA: 1, 0xF8: 0, 0xF9: 0, 0xFA: 0, 0xFB: 0, 0xFC: 0, 0xFD: 0, 0xFE: 0, 0xFF: 0,
}
# Variable commands: (header length, offset of the count in the header, count digits,
# bytes per counted unit)
VARIABLE = {0x92: (12, 8, 4, 1), 0x95: (4, 0, 4, 1), 0xA0: (4, 2, 2, 1), 0xA2: (4, 2, 2, 1),
            0xA4: (4, 2, 2, 1), 0xF0: (12, 8, 4, 1)}
MAX_COUNT = {0x92: 512, 0x95: RECEIVE_BUFFER - 5, 0xA0: 255, 0xA2: 255, 0xA4: 255,
             0xF0: RECEIVE_BUFFER - 13}

_HEXVAL = {c: int(chr(c), 16) for c in b"0123456789abcdefABCDEF"}
MEMORY_SIZE = 0x10000


def hex_value(field: bytes) -> int:
    value = 0
    for c in field:
        value = value * 16 + _HEXVAL.get(c, 0)
    return value


def put_hex(value: int, digits: int) -> bytes:
    return f"{value & ((1 << 4 * digits) - 1):0{digits}x}".encode()


def report_float(value: float) -> bytes:
    return float8.encode(value, b"\0")


class Command:
    """Robox and Pronterface protocols on the USB link."""

    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.buffer = bytearray()
        self.robox_mode = False
        self.last_ack_report = -1e9
        self.memory = bytearray(MEMORY_SIZE)  # the simulated address space of 0xf0
        self.paused_for = 0  # error bits that have already paused the job
        self.pending_after_reply = None  # reset or reprogram once the reply has left

    # ------------------------------------------------------------ errors
    @property
    def errors(self):
        return self.fw.errors

    def host_connected(self) -> bool:
        return self.fw.clock.now - self.last_ack_report < HOST_CONNECTED_S

    def pausing_errors(self) -> int:
        mask = PAUSE_MASK_CONNECTED if self.host_connected() else PAUSE_MASK
        return self.errors.bits & mask

    # ---------------------------------------------------------- the loop
    def maintain(self) -> None:
        link = self.fw.hw.usb
        if self.pending_after_reply is not None and not link.in_flight:
            action, self.pending_after_reply = self.pending_after_reply, None
            action()
            return
        space = RECEIVE_BUFFER - len(self.buffer)
        if space and link.received:
            self.buffer += link.device_take(space)
        if self.buffer:
            if self.robox_mode:
                self._robox()
            else:
                self._pronterface()
        fresh = self.pausing_errors() & ~self.paused_for
        if fresh:
            self.paused_for |= fresh
            self.fw.job.error_pause()

    def send(self, reply: bytes) -> None:
        if not self.fw.hw.usb.device_send(reply):
            self.errors.set(ErrorBit.USB_TX)

    def after_reply(self, action) -> None:
        """Run `action` once the reply now in flight has been read by the host."""
        self.pending_after_reply = action

    # ------------------------------------------------------ Pronterface
    def _pronterface(self) -> None:
        if self.buffer[0] >= 0x80:
            self.robox_mode = True
            self._robox()
            return
        end = next((i for i, c in enumerate(self.buffer) if c in (0x0A, 0x0D)), None)
        if end is None:
            if len(self.buffer) >= RECEIVE_BUFFER:
                self.buffer.clear()
                self.errors.set(ErrorBit.GCODE_LINE_TOO_LONG)
            return
        line = bytes(self.buffer[:end])
        stop = end + 1
        if stop < len(self.buffer) and self.buffer[stop] in (0x0A, 0x0D) and \
                self.buffer[stop] != self.buffer[end]:
            stop += 1  # CR LF or LF CR: one terminator
        line = strip_line_number(line.rstrip(b" \t"))
        if not line.strip():
            del self.buffer[:stop]
            return
        response = self.fw.job.execute_now(line)
        if response is None:
            return  # the execute buffer is full: the line waits, and so does the host
        del self.buffer[:stop]
        self.fw.activity()
        if response:
            self.send(response)  # a reporting code: its text and ok, now
        # otherwise the job engine sends ok once the line has run, as Marlin hosts expect

    # ---------------------------------------------------------- Robox
    def _robox(self) -> None:
        buf = self.buffer
        code = buf[0]
        if code < 0x80 or (code not in FIXED and code not in VARIABLE):
            del buf[0]
            self.errors.set(ErrorBit.BAD_COMMAND)
            return
        if code in FIXED:
            length = FIXED[code]
        else:
            header, at, digits, _ = VARIABLE[code]
            if len(buf) < 1 + header:
                self._abandon_if_interrupted(1, len(buf))
                return
            count = hex_value(buf[1 + at : 1 + at + digits])
            if count > MAX_COUNT[code]:
                del buf[: 1 + header]
                self.errors.set(ErrorBit.BAD_COMMAND)
                return
            length = header + count
        have = min(len(buf), 1 + length)
        if self._abandon_if_interrupted(1, have):
            return
        if len(buf) < 1 + length:
            return
        params = bytes(buf[1 : 1 + length])
        del buf[: 1 + length]
        self.fw.activity()
        try:
            self._dispatch(code, params)
        except Exception as exc:  # pragma: no cover - a model bug must not kill the printer
            self.fw.note_fault(exc)

    def _abandon_if_interrupted(self, start: int, end: int) -> bool:
        for i in range(start, end):
            if self.buffer[i] >= 0x80:
                del self.buffer[:i]
                self.errors.set(ErrorBit.USB_RX)
                return True
        return False

    def ack(self) -> None:
        self.last_ack_report = self.fw.clock.now
        self.send(b"\xe3" + self.errors.report())

    def _dispatch(self, code: int, p: bytes) -> None:
        fw = self.fw
        fs = fw.file_system
        if code in (0x90, 0x97):
            fs.start_write_file(p[:16], code == 0x97)
            fw.job.upload_started()
        elif code == 0x91:
            if fs.write_chunk(hex_value(p[:8]), p[8:520]):
                fw.job.data_arrived()
        elif code == 0x92:
            count = hex_value(p[8:12])
            if fs.end_write_file(hex_value(p[:8]), p[12 : 12 + count]):
                fw.job.data_arrived()
        elif code == 0x93:
            file_id, chunk = fs.send_file_report()
            self.send(b"\xe9" + file_id + put_hex(chunk, 8))
            return
        elif code == 0x94:
            fw.job.run_job(p[:16])
        elif code == 0x95:
            count = hex_value(p[:4])
            response = fw.job.execute_from_host(p[4 : 4 + count])
            self.send(b"\xe7" + put_hex(len(response), 4) + response)
            return
        elif code == 0x96:
            files = fs.file_list()
            self.send(b"\xe0" + put_hex(len(files), 2) + b"".join(files))
            return
        elif code == 0x98:
            if p[:1] == b"1":
                fw.job.pause()
            else:
                fw.job.resume()
        elif code in (0xA0, 0xA2, 0xA4):
            index = (code - 0xA0) // 2
            address, count = hex_value(p[:2]), hex_value(p[2:4])
            fw.eeproms.host_write(index, address, p[4 : 4 + count])
        elif code in (0xA1, 0xA3, 0xA5):
            index = (code - 0xA1) // 2
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
            self.paused_for = 0
        elif code == 0xC1:
            fw.parameters.write_unique_id(p)
        elif code in (0xC2, 0xC5):
            colour = (hex_value(p[0:2]), hex_value(p[2:4]), hex_value(p[4:6]))
            fw.user_interface.set_led(ambient=code == 0xC2, colour=colour)
        elif code == 0xC3:
            values = [float8.parse(p[i : i + 8]) for i in range(0, 56, 8)]
            fw.heaters.set_targets(values)
        elif code in (0xC4, 0xC7):
            fw.position.set_feed_rate_multiplier("D" if code == 0xC4 else "E",
                                                 max(0.0, float8.parse(p[:8])))
        elif code == 0xC6:
            fw.parameters.write_hours(p[:8])
        elif code in (0xC8, 0xC9):
            fw.position.set_filament_info("E" if code == 0xC8 else "D",
                                          max(0.1, float8.parse(p[:8])),
                                          max(0.0, float8.parse(p[8:16])))
        elif code == 0xCA:
            fw.user_interface.set_head_power(p[:1] == b"1")
        elif code == 0xF0:
            self.send(b"\xf0" + self._memory(p))
            return
        elif code in (0xF8, 0xF9, 0xFA):
            fw.eeproms.format(code - 0xF8)
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
            fw.job.abort_if_reading()
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

    def _memory(self, p: bytes) -> bytes:
        address = hex_value(p[:8]) % MEMORY_SIZE
        count = hex_value(p[8:12])
        digits = p[12 : 12 + count]
        for i in range(0, len(digits) - 1, 2):
            self.memory[(address + i // 2) % MEMORY_SIZE] = hex_value(digits[i : i + 2])
        data = bytes(self.memory[(address + i) % MEMORY_SIZE] for i in range(128))
        return data.hex().encode()

    # ------------------------------------------------------- status 0xe1
    def status_report(self) -> bytes:
        fw = self.fw
        job = fw.job
        machine = fw.hw.machine
        out = bytearray(b"\xe1")
        out += (job.job_id or bytes(ID_SIZE))
        out += put_hex(job.line_number, 8)
        out += job.pause_state_char() + job.busy_char()
        axes = machine.axes
        switches = [axes["X"].switch, axes["Y"].switch, axes["Z"].switch, False, False,
                    axes["B"].switch, machine.lid_closed, machine.button_pressed,
                    machine.filament_e, machine.filament_d, machine.z_top_switch]
        out += bytes(0x31 if s else 0x30 for s in switches)
        out += b"1" if fw.position.extruder_present("E") else b"0"
        out += b"1" if fw.position.extruder_present("D") else b"0"
        out += fw.heaters.report_block()
        out += fw.eeproms.status_characters()
        out += b"1" if fw.hw.card.present else b"0"
        for axis in "XYZB":
            out += report_float(fw.position.reported_position(axis))
        out += str(fw.position.tool).encode()
        for value in fw.position.filament_report():
            out += report_float(value)
        out += b"1" if machine.head_power else b"0"
        out += str(machine.hardware_revision % 10).encode()
        assert len(out) == 222, len(out)
        return bytes(out)


def strip_line_number(line: bytes) -> bytes:
    """Remove a leading N<number> and a trailing *<checksum> (Marlin-style hosts)."""
    text = line.lstrip()
    if text[:1] in (b"N", b"n"):
        i = 1
        while i < len(text) and (text[i : i + 1].isdigit() or (i == 1 and text[i:i + 1] == b"-")):
            i += 1
        if i > 1:
            text = text[i:].lstrip()
    star = text.rfind(b"*")
    if star >= 0 and text[star + 1 :].strip().isdigit():
        text = text[:star].rstrip()
    return text


"""The EEPROM object: head, reel 0 and reel 1 kept in RAM, chips maintained a byte at a time.

The state machine is spec/eeprom.md's. On every `maintain()` each of the three
EEPROMs takes one step, and a step is exactly one single-byte I2C transaction
at working bank + address counter:

- not VALID: read a byte into the buffer; after 196 bytes a good CRC makes it
  VALID, a bad one makes it PRESENT on bank 1 (both banks tried) and leaves
  it as it was on bank 0; either way the working bank flips.
- VALID: read and compare; a match advances (after 196 bytes the bank is
  verified and the working bank flips); a mismatch makes the next step a write
  of the buffer's byte, which the step after reads back.
- no acknowledged transaction for 0.2 s: NOT_PRESENT, counter 0, bank 0.

So after any change the working bank is rewritten and verified before the
other bank is touched: one bank always holds a complete, CRC-good copy.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import IntEnum
from typing import TYPE_CHECKING, Final

from robox.firmware.error_flags import ErrorFlags
from robox.formats import float8
from robox.formats.eeprom import (
    BANK_ADDRESSES,
    BANK_SIZE,
    DATA_SIZE,
    KIND_OF,
    EepromIndex,
    eeprom_crc,
    mask7,
)
from robox.formats.eeprom import field as field_named
from robox.formats.heads import max_temperature
from robox.formats.protocol import ErrorBit
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.packed import append, i64, vec

if TYPE_CHECKING:
    from robox.firmware.main import Firmware

#: No acknowledged transaction for this long: the EEPROM is gone.
TIMEOUT_S: Final = 0.2
#: Filament and head-hours bookkeeping period (0.002 h).
UPDATE_PERIOD_S: Final = 7.2
QUIET_STEP_S: Final = 0.01

#: The features a head type can have (bits of Eeproms._head_has).
DUAL_MATERIAL: Final = 1
TWO_FANS: Final = 2
B_AXIS: Final = 4
PRTD: Final = 8
#: Which type has each: the old type names that have it, and in the "RX" naming scheme
#: the character position whose digit, masked, must equal a value.
HEAD_FEATURES: Final = (
    (DUAL_MATERIAL, {b"RBX01-DM"}, 7, 3, 2),
    (TWO_FANS, {b"RBXDV-S3"}, 7, 4, 4),
    (B_AXIS, {b"RBX01-SM", b"RBX01-S2", b"RBX01-DM"}, 6, 1, 1),
    (PRTD, {b"RBXDV-S2"}, 6, 4, 4),
)


def _type_features(name: bytes) -> int:
    """The features (bits) of a head of type `name`, its first 8 bytes."""
    bits = 0
    for bit, old_names, at, mask, value in HEAD_FEATURES:
        if name in old_names or \
                (name[:2] == b"RX" and ((name[at] - 0x30) & 0xFF) & mask == value):
            bits |= bit
    return bits


ERROR_BIT: Final = {
    EepromIndex.HEAD: ErrorBit.HEAD_EEPROM,
    EepromIndex.REEL0: ErrorBit.REEL0_EEPROM,
    EepromIndex.REEL1: ErrorBit.REEL1_EEPROM,
}


class Status(IntEnum):
    NOT_PRESENT = 0
    PRESENT = 1
    VALID = 2


# The members as module constants, compared by identity: compiled, a class attribute
# lookup and an enum comparison become a pointer comparison.
NOT_PRESENT: Final = Status.NOT_PRESENT
PRESENT: Final = Status.PRESENT
VALID: Final = Status.VALID
# the EEPROMs' indices (EepromIndex), as plain numbers for the same reason
HEAD: Final = 0
REEL0: Final = 1
REEL1: Final = 2
# the banks' first addresses, held here (compiled: a static, not a lookup in another
# module's namespace on every step)
BANK0: Final = BANK_ADDRESSES[0]
BANK1: Final = BANK_ADDRESSES[1]


class EepromState:
    """What the firmware keeps for one EEPROM."""

    def __init__(self, index: EepromIndex, last_ack: float = 0.0) -> None:
        self.index = index
        self.status: Status = NOT_PRESENT
        #: The RAM copy of a bank: bytes, made anew by a change (see _spliced), where a
        #: bytearray's items and slices are generic lookups compiled.
        self.buffer = bytes(BANK_SIZE)
        self.working_bank = 0
        self.counter = 0
        self.writing = False
        self.last_ack = last_ack
        #: banks verified since the RAM copy last changed (2: the chip holds it twice)
        self.verified_banks = 0
        self.acked = True  # the last transaction was acknowledged (assumed at power-up)
        self.last_step = -1.0

    @property
    def data(self) -> bytes:
        return self.buffer[:DATA_SIZE]


def _spliced(buffer: bytes, offset: int, data: bytes) -> bytes:
    """`buffer` with `data` in place from `offset` on."""
    return buffer[:offset] + data + buffer[offset + len(data) :]


def _settled(state: EepromState) -> bool:
    """VALID, and both banks verified since the RAM copy last changed."""
    return state.status is VALID and state.verified_banks >= 2


def _given_up(state: EepromState, chip: EepromChip | None) -> bool:
    """An empty socket already given up: the step's read finds no chip, and its no-ack
    leaves everything as it is."""
    return chip is None and state.status is NOT_PRESENT \
        and not (state.counter or state.working_bank or state.writing)


class Eeproms:
    """The firmware object that owns the three EEPROMs."""

    # (set in initialise; the default only spares the compiled code a test at every
    # read of whether it was ever set)
    update_due: float = 0.0

    def __init__(self, bus: EepromBus, clock: SimClock, errors: ErrorFlags):
        self.bus = bus
        self.clock = clock
        self.errors = errors
        #: Called with the EepromIndex when an EEPROM becomes VALID.
        self.on_valid: list[Callable[[EepromIndex], None]] = []
        #: Called with the EepromIndex when a VALID EEPROM is lost.
        self.on_lost: list[Callable[[EepromIndex], None]] = []
        #: The firmware that owns this object (None when run alone, as by `eeprom set`).
        self.firmware: Firmware | None = None
        self._limit_of: bytes | None = None  # the head type head_max_temperature last read
        self._limit = 0.0
        # (asked at every heater sample, and kept for the head's bank they were read from:
        # an immutable bytes object, replaced whenever the EEPROM changes)
        self._features_of: bytes | None = None
        self._features = 0  # the head type's features (DUAL_MATERIAL and the rest)
        self._floats: dict[int, tuple[bytes, float]] = {}  # float_at's, by index and address
        self.initialise()

    def initialise(self) -> None:
        now = self.clock.now
        self.states = [EepromState(index, last_ack=now) for index in EepromIndex]
        # the three, and their statuses as the last pass left them, held one by one
        # (compiled: looked at on every pass as attributes, no list indexed)
        self._head, self._reel0, self._reel1 = self.states
        self._was_head: Status = NOT_PRESENT
        self._was_reel0: Status = NOT_PRESENT
        self._was_reel1: Status = NOT_PRESENT
        self.update_due = now + UPDATE_PERIOD_S

    def maintain(self) -> None:
        self._maintain_chips()
        self.after_steps()

    def after_steps(self) -> None:
        """The rest of a pass after the chips' steps: what appeared, the head's timeout
        and the bookkeeping."""
        fw = self.firmware
        if fw is None:
            return
        now = self.clock.now
        head, reel0, reel1 = self._head.status, self._reel0.status, self._reel1.status
        if head is not self._was_head or reel0 is not self._was_reel0 \
                or reel1 is not self._was_reel1:
            previous = [self._was_head, self._was_reel0, self._was_reel1]
            appeared = [s is VALID and p is not VALID
                        for s, p in zip([head, reel0, reel1], previous, strict=True)]
            self._was_head, self._was_reel0, self._was_reel1 = head, reel0, reel1
            if appeared[HEAD]:
                fw.file_system.check_for_head_change(self.head_dual_material())
            if any(appeared):
                fw.heaters.targets_from_reel()
                fw.position.filament_info_from_reel()
        if now - self._head.last_ack >= TIMEOUT_S:
            fw.heaters.shut_down_head_due_to_eeprom()
        if now >= self.update_due:
            if fw.heaters.head_hot():
                self.write_float_at(EepromIndex.HEAD, 0xB8,
                                    self.float_at(EepromIndex.HEAD, 0xB8, 0.0) + 0.002)
            fw.position.update_reel_filament_length()
            self.update_due = now + UPDATE_PERIOD_S

    def _maintain_chips(self) -> None:
        now = self.clock.now
        bus = self.bus
        for state in self.states:
            # A settled EEPROM's verify step only reads what it already holds: it is
            # taken at most every QUIET_STEP_S, which still sees an unplug well within
            # the timeout (the spec's "accounted for without being replayed").
            if now - state.last_step < QUIET_STEP_S and state.status is VALID \
                    and state.verified_banks >= 2:
                continue
            state.last_step = now
            chip = bus.chip(state.index)
            if _given_up(state, chip):
                state.acked = False
                continue
            self._step(state, chip)

    # ----------------------------------------------------------- one step
    def _address(self, state: EepromState) -> int:
        return (BANK1 if state.working_bank else BANK0) + state.counter

    def _step(self, state: EepromState, chip: EepromChip | None) -> None:
        """One step, its transaction made with `chip`, the chip the bus reaches in the
        EEPROM's socket (None: none, and the transaction goes unacknowledged)."""
        address = self._address(state)
        if state.status is VALID:
            if chip is None:
                self._no_ack(state)
                return
            if state.writing:
                if not chip.write(address, state.buffer[state.counter]):
                    self._no_ack(state)
                    return
                state.acked = True
                state.last_ack = self.clock.now
                state.writing = False  # the next step reads it back
                return
            # read and compare (compiled: the byte stays a native number)
            found = chip.read_matches(address, state.buffer[state.counter])
            if found < 0:
                self._no_ack(state)
                return
            state.acked = True
            state.last_ack = self.clock.now
            if found:
                self._advance(state)
            else:
                state.writing = True
            return
        value = None if chip is None else chip.read(address)
        if value is None:
            self._no_ack(state)
            return
        state.acked = True
        state.last_ack = self.clock.now
        state.buffer = _spliced(state.buffer, state.counter, bytes((value,)))
        state.counter += 1
        if state.counter < BANK_SIZE:
            return
        if eeprom_crc(state.buffer) == 0:
            state.verified_banks = 1  # the bank just loaded
            self._become(state, VALID)
        elif state.working_bank == 1:
            self._become(state, PRESENT)
        state.working_bank ^= 1
        state.counter = 0

    def _advance(self, state: EepromState) -> None:
        state.counter += 1
        if state.counter == BANK_SIZE:
            state.counter = 0
            state.working_bank ^= 1
            state.verified_banks += 1

    def _no_ack(self, state: EepromState) -> None:
        state.acked = False
        if self.clock.now - state.last_ack < TIMEOUT_S:
            return
        was_valid = state.status is VALID
        state.status = NOT_PRESENT
        state.counter = 0
        state.working_bank = 0
        state.writing = False
        if was_valid:
            for listener in self.on_lost:
                listener(state.index)

    def _become(self, state: EepromState, status: Status) -> None:
        was_valid = state.status is VALID
        state.status = status
        if status is VALID and not was_valid:
            for listener in self.on_valid:
                listener(state.index)

    # ----------------------------------------------------- buffer changes
    def _change(self, state: EepromState, data: bytes, offset: int = 0) -> bool:
        """Write masked bytes into the RAM copy; a real change restarts verification."""
        end = min(offset + len(data), DATA_SIZE)
        new = mask7(data[: max(0, end - offset)])
        if state.buffer[offset:end] == new:
            return False
        data = _spliced(state.buffer[:DATA_SIZE], offset, new)
        state.buffer = data + struct.pack("<I", eeprom_crc(data))
        state.counter = 0
        state.writing = False
        state.verified_banks = 0
        return True

    # ----------------------------------------------------------- host side
    def status(self, index: EepromIndex) -> Status:
        return self.states[index].status

    def status_characters(self) -> bytes:
        """The four characters of the status report: three states and the mux flag."""
        out = bytearray(b"0000")
        states = self.states
        k: i64
        for k in range(3):  # (a buffer: compiled, no generator is made)
            out[k] = 0x30 + int(states[k].status)
        if self.bus.mux_present:
            out[3] = 0x31
        return bytes(out)

    def host_write(self, index: EepromIndex, address: int, data: bytes) -> bool:
        """Write from the host; bytes beyond address 191 are ignored."""
        state = self.states[index]
        if state.status is not VALID:
            self.errors.set(ERROR_BIT[index])
            return False
        if address < DATA_SIZE and self._change(state, data, address) and \
                index != EepromIndex.HEAD and self.firmware is not None:
            # a reel's new contents take effect at once, as when a reel appears
            self.firmware.heaters.targets_from_reel()
            self.firmware.position.filament_info_from_reel()
        return True

    def host_read(self, index: EepromIndex) -> bytes:
        """192 bytes masked to 7 bits; zeros (and the EEPROM's error) when not VALID."""
        state = self.states[index]
        if state.status is not VALID:
            self.errors.set(ERROR_BIT[index])
            return bytes(DATA_SIZE)
        return mask7(state.data)

    def format(self, index: EepromIndex) -> None:
        """Zero the data, mark VALID; the chip is rewritten by the normal process."""
        state = self.states[index]
        state.buffer = bytes(DATA_SIZE) + struct.pack("<I", eeprom_crc(bytes(DATA_SIZE)))
        state.counter = 0
        state.writing = False
        state.verified_banks = 0
        # VALID at once; with no chip there, the next pass's timeout takes it away
        state.status = VALID

    # ------------------------------------------------- firmware's own fields
    def valid(self, index: EepromIndex) -> bool:
        return self.states[index].status is VALID

    def float_at(self, index: EepromIndex, address: int, default: float) -> float:
        """The 8-character number at `address`, as strtof reads it; `default` unless VALID."""
        state = self.states[index]
        if state.status is not VALID:
            return default
        bank = state.buffer
        key = (int(index) << 16) | address
        kept = self._floats.get(key)
        if kept is not None and kept[0] is bank:
            return kept[1]
        value = float8.parse(bank[address : address + 8].split(b"\0", 1)[0])
        self._floats[key] = (bank, value)
        return value

    def write_float_at(self, index: EepromIndex, address: int, value: float) -> None:
        """Store `value` as printf("%f") cut to 8 characters. Like the firmware, this
        restarts the verify cycle even when the text is unchanged."""
        state = self.states[index]
        if state.status is not VALID or address > DATA_SIZE - 8:
            return
        data = _spliced(state.buffer[:DATA_SIZE], address, float8.encode(value))
        state.buffer = data + struct.pack("<I", eeprom_crc(data))
        state.counter = 0
        state.writing = False
        state.verified_banks = 0

    def _head_type(self) -> bytes | None:
        state = self.states[HEAD]
        return state.buffer[:8] if state.status is VALID else None

    def _head_has(self, bit: int) -> bool:
        state = self.states[HEAD]
        bank = state.buffer if state.status is VALID else None
        if bank is not self._features_of:
            self._features = 0 if bank is None else _type_features(bank[:8])
            self._features_of = bank
        return self._features & bit != 0

    def head_dual_material(self) -> bool:
        return self._head_has(DUAL_MATERIAL)

    def head_has_two_fans(self) -> bool:
        return self._head_has(TWO_FANS)

    def head_has_b_axis(self) -> bool:
        return self._head_has(B_AXIS)

    def head_has_prtd(self) -> bool:
        return self._head_has(PRTD)

    def head_max_temperature(self) -> float:
        name = self._head_type()
        key = name if name is not None else b""
        # (asked at every heater sample: the type's limit is kept for the type last seen)
        if key != self._limit_of:
            self._limit = max_temperature(key)
            self._limit_of = key
        return self._limit

    def get_float(self, index: EepromIndex, name: str) -> float:
        f = field_named(KIND_OF[index], name)
        return float8.parse(self.states[index].buffer[f.offset : f.offset + f.size])

    def set_float(self, index: EepromIndex, name: str, value: float) -> bool:
        state = self.states[index]
        if state.status is not VALID:
            return False
        f = field_named(KIND_OF[index], name)
        self._change(state, float8.encode(value), f.offset)
        return True

    def settled(self, index: int) -> bool:
        """True unless a VALID EEPROM's chip may still differ from its RAM copy."""
        state = self.states[index]
        return state.status is not VALID or state.verified_banks >= 2

    def all_quiet(self) -> bool:
        """quiet() of all three (asked on every pass: one loop, no call per EEPROM)."""
        for state in self.states:
            status = state.status
            if status is NOT_PRESENT:
                if state.acked:
                    return False
            elif status is VALID and state.verified_banks < 2:
                return False
        return True

    def run_inert_passes(self, dt: float, most: int) -> int:
        """Run up to `most` passes of `dt` (the clock moved on pass by pass) in which this
        object's steps change nothing any other object looks at, and return how many ran.

        A loading or verifying EEPROM takes one step a pass; while those steps are
        acknowledged reads that neither end a bank nor find a byte to rewrite, they are
        taken together at the end, as the reads they are. A settled EEPROM's steps (one
        every QUIET_STEP_S) are taken at their own passes. The run stops before any
        other step, so the next pass finds things as the passes one by one would have
        left them."""
        clock = self.clock
        most = self._inert_most(clock.now + dt, most)
        if most < 0:
            return 0
        settled = []
        loading = []  # the loading or verifying ones, each with its chip
        for state in self.states:
            if _settled(state):
                settled.append(state)
                continue
            chip = self.bus.chip(state.index)
            if chip is not None:  # (else given up: _inert_most saw no other kind)
                loading.append((state, chip))
        if not settled:
            clock.advance(dt, most)
            for state, chip in loading:
                self._take_reads(state, chip, most)
            return most
        done = 0
        while done < most:
            # the passes before a settled EEPROM is due to step again move the clock alone
            # (the clock adds them one by one, as `now` does here)
            oldest = min(state.last_step for state in settled)
            now, idle = clock.now, 0
            while done + idle < most and now + dt - oldest < QUIET_STEP_S:
                now += dt
                idle += 1
            if idle:
                clock.advance(dt, idle)
                done += idle
                continue
            at = clock.now + dt
            due = [state for state in settled if at - state.last_step >= QUIET_STEP_S]
            if due and not all(self._inert_steps(state, self.bus.chip(state.index), at, 1)
                               for state in due):
                break
            clock.advance(dt)
            done += 1
            for state in due:
                state.last_step = clock.now
                self._step(state, self.bus.chip(state.index))
        for state, chip in loading:
            self._take_reads(state, chip, done)
        return done

    def light_steps(self, at: float) -> bool:
        """Whether the steps of a pass at `at` change nothing another object looks at,
        though they may not be inert: each EEPROM that steps is a verifying one whose
        read or write is answered and does not end its bank (a read that finds a byte
        to rewrite, the write, the read back), or a settled one taking an inert read.
        No status changes and no bank is verified, so quiet() and every listener see
        what they saw before (Firmware._step_pass)."""
        for state in self.states:
            if state.status is VALID and state.verified_banks >= 2:
                if at - state.last_step >= QUIET_STEP_S \
                        and self._inert_steps(state, self.bus.chip(state.index), at, 1) == 0:
                    return False
                continue
            chip = self.bus.chip(state.index)
            if state.status is not VALID:
                if _given_up(state, chip):
                    continue
                return False
            if chip is None or not chip.will_acknowledge(at):
                return False
            if not state.writing and state.counter == BANK_SIZE - 1 \
                    and chip.peek_run(self._address(state), 1)[0] == state.buffer[state.counter]:
                return False  # the read that verifies the bank
        return True

    def inert_passes(self, dt: float, most: int) -> int:
        """How many passes `run_inert_passes(dt, most)` would run from now, found without
        running them: the loop runs motion ahead only as far as the EEPROMs' steps in
        the passes it skips are inert."""
        now = self.clock.now
        most = self._inert_most(now + dt, most)
        if most < 0:
            return 0
        settled = [state for state in self.states if _settled(state)]
        if not settled:
            return most
        # a settled EEPROM steps every QUIET_STEP_S; the first of its steps found not to
        # be inert ends the run (each inert step moves it one byte on, so its k-th step
        # from now is inert while k is below what the first finds). (Native locals and
        # packed vectors: compiled, the walk runs before each run ahead, and boxed times
        # in lists were most of its cost.)
        n: i64 = most
        last = vec[float]()
        left = vec[i64]()
        for state in settled:
            last = append(last, state.last_step)
            left = append(left, -1)
        t = now
        j: i64
        k: i64
        for k in range(n):
            t += dt
            for j in range(len(settled)):
                if t - last[j] < QUIET_STEP_S:
                    continue
                if left[j] < 0:
                    # (no more than the passes left: a step a pass at the most)
                    state = settled[j]
                    left[j] = self._inert_steps(state, self.bus.chip(state.index), t, n - k)
                if left[j] == 0:
                    return k
                left[j] -= 1
                last[j] = t
        return n

    def _inert_most(self, at: float, most: i64) -> i64:
        """`most` cut to the inert steps the loading or verifying EEPROMs have from a pass
        at `at` on; -1 when an EEPROM in use has lost its chip (its next step is no inert
        read). (Nothing made: compiled, this is asked before every run ahead.)"""
        for state in self.states:
            if _settled(state):
                continue
            chip = self.bus.chip(state.index)
            if _given_up(state, chip):
                continue
            if chip is None:
                return -1
            steps: i64 = self._inert_steps(state, chip, at, most)
            if steps < most:
                most = steps
        return most

    def _inert_steps(self, state: EepromState, chip: EepromChip | None, at: float,
                     most: int) -> int:
        """How many steps from a pass at `at` on are acknowledged reads that change
        nothing but this EEPROM's place in its bank (a bank's last byte is left out: its
        step loads or verifies the bank, which another object, or quiet(), sees), counted
        no further than `most`: a verifying EEPROM's bytes are compared only that far."""
        if chip is None or state.writing or not chip.will_acknowledge(at):
            return 0
        n = BANK_SIZE - 1 - state.counter
        if chip.faults.unplug_at is not None and chip.faults.unplug_at > chip.transactions:
            n = min(n, chip.faults.unplug_at - chip.transactions - 1)
        if n > most:
            n = most
        if state.status is not VALID or n <= 0:
            return max(0, n)
        address = self._address(state)
        held: bytes = chip.peek_run(address, n)
        want = state.buffer[state.counter : state.counter + n]
        if held == want:
            return n
        i = 0  # the first byte to rewrite (both are n long and differ, so one does)
        while held[i] == want[i]:
            i += 1
        return i

    def _take_reads(self, state: EepromState, chip: EepromChip, n: int) -> None:
        """`n` inert steps of a loading or verifying EEPROM, the last at the clock's now."""
        if n == 0:
            return
        data = chip.read_run(self._address(state), n)
        now = self.clock.now
        state.acked = True
        state.last_ack = state.last_step = now
        if state.status is VALID:
            state.counter += n
        else:
            state.buffer = _spliced(state.buffer, state.counter, data)
            state.counter += n

    def quiet(self, index: int) -> bool:
        """True when stepping this EEPROM now would change nothing but the time: it is
        settled, or not answering, or answering with no good bank (PRESENT)."""
        state = self.states[index]
        if state.status is NOT_PRESENT:
            return not state.acked
        return self.settled(index)

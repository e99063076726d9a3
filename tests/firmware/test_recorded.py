"""Behaviours learned from host sessions recorded from the real firmware
(../shared/conformance): each test replays a few recorded steps with their bytes and
expects exactly the bytes the real firmware answered."""

import pytest

from robox.sim.printer import VirtualPrinter

STEP_S = 0.3


@pytest.fixture
def printer():
    p = VirtualPrinter(card_blocks=16384)
    p.run_until(lambda: False, 2.0)  # the recordings start 2 s after power-up
    return p


def robox(p, data: bytes) -> bytes:
    """A Robox-mode step: write, then read the report that comes back."""
    from robox.formats.protocol import reply_length

    p.usb.host_write(data)
    p.run_until(lambda: p.usb.reply_waiting > 0, STEP_S)
    out = b""
    while p.usb.reply_waiting:
        out += p.usb.host_read(64)
        n = reply_length(out)
        if n is not None and len(out) >= n:
            break
        if not p.usb.reply_waiting:
            p.run_until(lambda: p.usb.reply_waiting > 0, STEP_S)
    return out


def line(p, data: bytes) -> bytes:
    """A Pronterface step: write, then collect until the output is quiet for 50 ms."""
    p.usb.host_write(data)
    p.run_until(lambda: p.usb.reply_waiting > 0, STEP_S)
    out = b""
    while True:
        while p.usb.reply_waiting:
            out += p.usb.host_read(64)
        if not p.run_until(lambda: p.usb.reply_waiting > 0, 0.05):
            return out


ACK_CLEAN = b"\xe3" + b"0" * 64


def test_status_at_power_up(printer):
    # recorded (mixed, seed 0, step 0), less the measured temperatures check.py masks
    status = robox(printer, b"\xb0")
    assert status[17:40] == b"0000000000" + b"1110011" + b"1" + b"100" + b"10"
    assert status[40:41] + status[49:65] == b"0210.0000210.0000"
    assert status[65:66] + status[74:90] == b"0210.0000210.0000"  # nozzle 1: from reel 0
    assert status[90:91] + status[99:115] == b"055.0000060.00000"
    assert status[115:116] + status[124:134] == b"035.0000000"
    assert status[134:172] == b"2200" + b"1" + b"0.000000" * 4 + b"0"
    assert status[172:222] == b"1.7500001.0000001.7500001.0000001.0000001.000000" + b"12"


def test_m104_s0_turns_off_but_keeps_the_target_and_m109_s_is_ignored(printer):
    assert line(printer, b"M104 S200\n") == b"ok\r\n"
    assert line(printer, b"M104 S0\r\n") == b"ok\r\n"
    assert line(printer, b"M109 S0 ; comment\n") == b"ok\r\n"  # nozzle off: no wait
    status = robox(printer, b"\xb0")
    assert status[40:41] + status[49:57] == b"0200.0000"


def test_m109_with_the_nozzle_off_has_ended_by_the_next_command(printer):
    # recorded (mixed, seed 231, steps 10-11): the wait is taken, then a status report
    # asked for at once shows no line under way and nothing waited for; the line looks
    # at its heater at the pass after it begins to wait, while the report's packet is
    # on its way in
    assert robox(printer, b"\x950012M109 S0 ; comment\r") == b"\xe70000"
    status = robox(printer, b"\xb0")
    assert status[17:27] == b"0000000000" and status[132:134] == b"00"


def test_bed_and_ambient_targets_clamp(printer):
    # recorded 0xc3 with 999 for the bed targets and 100 for ambient (seed 80, step 10)
    targets = b"35.000000.000000200.0000210.5000999.0000999.0000100.0000"
    assert robox(printer, b"\xc3" + targets)[:1] == b"\xe3"
    status = robox(printer, b"\xb0")
    assert status[99:115] == b"160.0000160.0000" and status[124:132] == b"60.00000"


def test_m111_to_m113_and_m999_report_deltas(printer):
    assert robox(printer, b"\x950005M112\n") == b"\xe70015Ydelta:0.000000\r\nok\r\n"
    assert robox(printer, b"\x950005M113\r") == b"\xe70015Zdelta:0.000000\r\nok\r\n"


def test_a_reporting_0x95_runs_only_its_first_line(printer):
    # the M in a comment makes the text "reporting"; its first line runs at once
    assert robox(printer, b"\x95000eM82 ; comment ") == b"\xe70000"  # no line end yet
    assert robox(printer, b"\x950011G1 X10 Y10 F3000\n") == b"\xe70000"  # queued


def test_1024_bytes_with_no_line_end_leave_the_printer_deaf(printer):
    assert line(printer, b"M115" + b" " * 1020) == b""
    assert printer.firmware.command.deaf
    assert ("deaf", printer.firmware.events[-1][1]) == printer.firmware.events[-1]
    assert line(printer, b"\nM115\n") == b""  # nothing is read any more


def test_run_job_with_an_unknown_id_closes_the_read_file(printer):
    assert robox(printer, b"\x94JOBBBBB000000002") == ACK_CLEAN
    status = robox(printer, b"\xb0")
    assert status[1:17] == bytes(16) and status[17:27] == b"0000000000"


def test_a_chunk_before_any_start_file_is_a_sequence_error(printer):
    reply = robox(printer, b"\x91" + b"00000000" + b"G90\n".ljust(512, b"\n"))
    assert reply == b"\xe3" + b"01" + b"0" * 62


def test_formatting_an_absent_reel_eeprom_does_not_stick(printer):
    assert robox(printer, b"\xfa") == ACK_CLEAN
    status = robox(printer, b"\xb0")
    assert status[134:138] == b"2200"


def test_run_last_job_opens_a_newer_file_stored_with_an_empty_id(printer):
    # files seed 49, steps 140-147: a file stored with an empty id matches the empty id of
    # "run the last job", so it is opened for reading and the next upload keeps it
    assert robox(printer, b"\x90" + bytes(16)) == b"\xe3" + b"0" * 64
    assert robox(printer, b"\x92" + b"00000000" + b"0007" + b"G4 S10\n") == b"\xe3" + b"0" * 64
    assert robox(printer, b"\x94" + bytes(16)) == b"\xe3" + b"0" * 64  # runs, still reading
    assert robox(printer, b"\x90F00" + bytes(13)) == b"\xe3" + b"0" * 64
    assert robox(printer, b"\x92" + b"00000000" + b"0004" + b"M107") == b"\xe3" + b"0" * 64
    assert robox(printer, b"\x96") == b"\xe002" + bytes(16) + b"F00" + bytes(13)


# --------------------------------------------------------------- mechanics
def wait(p, seconds: float) -> bytes:
    """A recorded wait: the printer runs on; whatever it says is collected."""
    p.run_until(lambda: False, seconds)
    out = b""
    while p.usb.reply_waiting:
        out += p.usb.host_read(64)
    return out


def gcode(p, text: bytes) -> bytes:
    return robox(p, b"\x95" + f"{len(text):04x}".encode() + text)


def head_b_offsets(p, nozzle0: bytes, nozzle1: bytes) -> None:
    """The mechanics sessions start by writing the head's B offsets (0x58, 0x88)."""
    assert robox(p, b"\xa0" + b"5808" + nozzle0) == ACK_CLEAN
    assert robox(p, b"\xa0" + b"8808" + nozzle1) == ACK_CLEAN


def queue(p, text: bytes, then_wait: float) -> None:
    """A queued line (answered with no text) and the recorded wait after it."""
    assert gcode(p, text) == b"\xe70000"
    assert wait(p, then_wait) == b""


def report(p, text: bytes) -> bytes:
    """A reporting line's text; the length in the 0xe7 header must match it."""
    reply = gcode(p, text)
    assert reply[:1] == b"\xe7" and int(reply[1:5], 16) == len(reply) - 5
    return reply[5:]


def test_homing_and_moves_book_the_steps_made(printer):
    # recorded (mechanics, seed 0): G28 measures X's distance to its switch; M114 shows
    # where whole steps took the head, and mid-move where the interrupts have got to
    head_b_offsets(printer, b"0.650000", b"-0.70000")
    queue(printer, b"G28 X Y Z\n", 7.6)
    assert report(printer, b"M111\n") == b"Xdelta:-0.493835\r\nok\r\n"
    assert wait(printer, 4.2) == b""
    queue(printer, b"G36 E20\n", 6.0)  # no filament: nothing to slip
    queue(printer, b"G0 Y155\n", 5.5)
    assert report(printer, b"M114\n") == b"X:0.000000 Y:154.996384 Z:0.000000 B:0.000000 T:0" \
        b"\r\nok\r\n"
    queue(printer, b"G1 X10 Y50 F12000\n", 2.6)
    assert report(printer, b"M114\n") == b"X:10.000004 Y:50.000107 Z:0.000000 B:0.000000 T:0" \
        b"\r\nok\r\n"
    robox(printer, b"\xb0")
    queue(printer, b"G1 X226 Y100 F3000\n", 3.7)
    assert report(printer, b"M114\n") == \
        b"X:192.917023 Y:92.341278 Z:0.000000 B:0.000000 T:0\r\nok\r\n"


def test_t1_makes_the_valve_position_negative(printer):
    # recorded (mechanics, seed 55): the valve of nozzle 1 is B's negative side, so
    # after T1 a homed, closed valve reads -0.000000; M119's B switch is open there
    head_b_offsets(printer, b"0.700000", b"-0.70000")
    queue(printer, b"G1 Z1 F600\n", 5.6)  # Z not homed: no move
    assert report(printer, b"M114\n") == b"X:0.000000 Y:0.000000 Z:0.000000 B:0.000000 T:0" \
        b"\r\nok\r\n"
    queue(printer, b"T1\n", 3.3)
    assert report(printer, b"M114\n") == b"X:0.000000 Y:0.000000 Z:0.000000 B:0.000000 T:1" \
        b"\r\nok\r\n"
    assert wait(printer, 8.0) == b""
    queue(printer, b"G28 Z\n", 6.2)
    assert report(printer, b"M114\n") == b"X:0.000000 Y:0.000000 Z:0.000000 B:-0.000000 T:1" \
        b"\r\nok\r\n"
    assert report(printer, b"M119\n") == \
        b"M119 X:1 Y:1 Z:0 Z+:0 E:0 D:0 B:0 Eindex:1 Dindex:0\r\nok\r\n"
    queue(printer, b"G0 B1\n", 1.6)
    assert report(printer, b"M114\n") == b"X:0.000000 Y:0.000000 Z:0.000000 B:1.000000 T:1" \
        b"\r\nok\r\n"


# recorded (mixed, seed 31, steps 0-2): the chunk's 512 bytes, as the host sent them
SEED31_CHUNK_LINES = (
    b"G1 X1 Y1 F1200\nM104 S0\nG92 E0\nG1 X0 Y0\nM106 S0\nG92 E0\nG1 E0.1 F300\n"
    b"G1 E0.1 F300\nG1 X1 Y1 F1200\nM106 S0\nG90\nG92 E0\nG92 E0\nG90\nM106 S0\nG90\n"
    b"G92 E0\nG92 E0\nG92 E0\nM106 S0\nG1 X1 Y1 F1200\nG1 X1 Y1 F1200\nM104 S0\nG90\n"
    b"M104 S0\nG92 E0\nM104 S0\nM106 S0\nG1 X1 Y1 F1200\nG1 E0.1 F300\nG1 X0 Y0\n"
    b"G92 E0\nG92 E0\nM106 S0\nG90\nG92 E0\nG90\nG92 E0\nG1 X0 Y0\nG1 X1 Y1 F1200\n"
    b"; layer\nG90\n; layer\nG90\nM106 S0\nG1 X0 Y0\nG90\nG92 E0\nG1 E0.1 F300\n"
    b"; layer\nM104 S0\n; layer\nG1 E0.1 F300\nM104 S0\nG92 E0\nG1 X1 Y1 F1200\nG90\n"
    b"G1 E0.1 F300\nM106 S0\n; layer\n; l"
)


def test_a_frame_inside_an_unfinished_text_line_is_text(printer):
    # A Pronterface line left without its end makes the next bytes text, frame codes and
    # all: the chunk's 59 line ends complete 60 lines (the first holds "G1 E1 F300",
    # 0xa1, 0x91 and the chunk number), every one answered "ok", all read as one reply.
    assert len(SEED31_CHUNK_LINES) == 512
    assert line(printer, b"G1 E1 F300") == b""
    assert robox(printer, b"\xa1") == b""
    reply = robox(printer, b"\x91ffffffff" + SEED31_CHUNK_LINES)
    assert reply == b"ok\r\n" * 60
    assert not printer.firmware.command.robox_mode
    assert robox(printer, b"\xff") == b""  # the unfinished "; l" takes it as text too



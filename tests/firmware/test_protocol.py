"""The USB protocol byte for byte: every command's reply, both modes, partial commands,
resynchronisation, the error flags and the one-reply-in-flight rule."""

import re

import pytest

from robox.formats.protocol import ErrorBit
from tests.firmware.wire import float8, hexn, ident, job_text


def test_ack_is_64_characters_of_error_bits(wire):
    wire.fw.errors.set(ErrorBit.FILE_TOO_LARGE)
    wire.fw.errors.set(ErrorBit.BED_TEMPERATURE_DROOP)
    reply = wire.raw(b"\xb3")
    expected = ["0"] * 64
    expected[2] = expected[41] = "1"
    assert reply == b"\xe3" + "".join(expected).encode()
    assert wire.raw(b"\xc0") == b"\xe3" + b"0" * 64  # cleared before the ack


def test_revision_unique_id_hours_sd_state(wire):
    assert wire.raw(b"\xb4") == b"\xe4" + b"r776sim\0"
    assert wire.raw(b"\xb2") == b"\xe5" + b"RBXSIM0000000001".ljust(256, b"\0")
    assert wire.raw(b"\xb6") == b"\xea" + b"0.000000"
    assert wire.raw(b"\xbb") == b"\xeb1"
    wire.printer.hw.card.remove()
    assert wire.raw(b"\xbb") == b"\xeb0"


def test_unique_id_and_hours_are_written_masked_and_persist_in_flash(wire):
    uid = bytes(range(0x20, 0x7F)).ljust(256, b"Z")
    wire.ok(b"\xc1" + uid)
    assert wire.raw(b"\xb2") == b"\xe5" + uid
    wire.ok(b"\xc6" + b"123.4560")
    assert wire.raw(b"\xb6") == b"\xea" + b"123.4560"
    assert wire.printer.hw.flash.page(511) == uid


def test_eeprom_read_and_write_reports(wire):
    reel = wire.raw(b"\xa3")
    assert reel[0] == 0xE6 and len(reel) == 193
    assert reel[1:17] == b"RBX-PLA-SIM".ljust(16, b"\0")
    assert reel[1 + 0x50 : 1 + 0x58] == b"1.750000"
    wire.ok(b"\xa2" + hexn(0x68, 2) + hexn(5, 2) + b"Hello")
    assert wire.raw(b"\xa3")[1 + 0x68 : 1 + 0x6D] == b"Hello"
    head = wire.raw(b"\xa1")
    assert head[0] == 0xE2 and head[1:9] == b"RBX01-SM"
    absent = wire.raw(b"\xa5")  # reel 1: no dual-reel adaptor
    assert absent == b"\xe8" + bytes(192)
    assert wire.ack(b"\xb3")[ErrorBit.REEL1_EEPROM] == "1"


def test_format_eeprom_zeroes_it(wire):
    wire.ok(b"\xf9")
    assert wire.raw(b"\xa3") == b"\xe6" + bytes(192)


def test_debug_and_board_test_reports_are_256_bytes(wire):
    debug = wire.raw(b"\xfb")
    assert debug[0] == 0xFB and debug[1:].rstrip(b"\0").startswith(b"robox model")
    board = wire.raw(b"\xfc")
    assert board[0] == 0xEF and len(board) == 257


def test_memory_command_uses_a_simulated_address_space(wire):
    reply = wire.raw(b"\xf0" + hexn(0x1234, 8) + hexn(6, 4) + b"a1b2c3")
    assert reply[0] == 0xF0 and reply[1:7] == b"a1b2c3" and reply[7:] == b"00" * 125
    again = wire.raw(b"\xf0" + hexn(0x1233, 8) + hexn(0, 4))
    assert again[1:9] == b"00a1b2c3"
    huge = wire.raw(b"\xf0" + b"ffffffff" + hexn(0, 4))  # wraps inside the model
    assert len(huge) == 257


def status_fields(report: bytes) -> dict:
    assert report[0] == 0xE1 and len(report) == 222
    f = {"job": report[1:17], "line": report[17:25], "pause": report[25:26],
         "busy": report[26:27], "switches": report[27:38], "extruders": report[38:40],
         "eeproms": report[134:138], "sd": report[138:139], "tool": report[171:172],
         "head_power": report[220:221], "hw_rev": report[221:222]}
    for name, start in (("nozzle0", 40), ("nozzle1", 65), ("bed", 90)):
        f[name] = (report[start : start + 1], report[start + 1 : start + 9],
                   report[start + 9 : start + 17], report[start + 17 : start + 25])
    f["ambient"] = (report[115:116], report[116:124], report[124:132])
    f["fan"], f["why"] = report[132:133], report[133:134]
    f["positions"] = [report[139 + 8 * i : 147 + 8 * i] for i in range(4)]
    f["filament"] = [report[172 + 8 * i : 180 + 8 * i] for i in range(6)]
    return f


def nul8(value: float) -> bytes:
    return f"{value:f}"[:8].encode().ljust(8, b"\0")


def test_status_report_field_by_field(wire):
    wire.printer.run_until(lambda: False, 1.1)  # temperatures read 0 until the first sample
    wire.ok(b"\xc3" + b"".join(float8(v) for v in (215, 220, 0, 0, 60, 65, 30)))
    wire.ok(b"\xc8" + float8(2.85) + float8(0.95))
    wire.ok(b"\xc7" + float8(1.1))
    wire.ok(b"\xc4" + float8(-3))  # clamped to 0
    wire.ok(b"\xca" + b"0")
    f = status_fields(wire.raw(b"\xb0"))
    assert f["job"] == bytes(16) and f["line"] == b"00000000"
    assert f["pause"] == b"0" and f["busy"] == b"0"
    # X Y Z at home, E D no filament, B at home, lid closed, button pin (high: up),
    # E index, D index, Z top
    assert f["switches"] == b"11100111100"
    assert f["extruders"] == b"10"  # single-material head
    assert f["nozzle0"] == (b"0", nul8(20.0), nul8(215), nul8(220))
    assert f["bed"][2:] == (nul8(60), nul8(65)) and f["ambient"][2] == nul8(30)
    assert f["eeproms"] == b"2200" and f["sd"] == b"1" and f["tool"] == b"0"
    assert f["positions"] == [nul8(0.0)] * 4
    assert f["filament"] == [nul8(2.85), nul8(0.95), nul8(1.75), nul8(1.0), nul8(0.0),
                             nul8(1.1)]
    assert f["head_power"] == b"0" and f["hw_rev"] == b"2"  # revision 2 hardware


def test_the_status_report_follows_each_change_of_what_it_keeps(wire):
    """The report keeps the last field of each position figure and whether the head is
    dual-material, and works out again only what changed: the positions follow the
    head report after report (an axis that stood reads as before, B's -0.0 under T1
    reads as such, not as the 0.0 it equals), and a head swapped for a dual-material
    one shows both extruders."""
    from robox.firmware.cline import report_float
    from robox.sim import images

    p = wire.fw.position

    def fresh() -> list[bytes]:  # each figure worked out anew
        return [report_float(v, False) for v in p._shown()]

    reports = []
    for x, tool in ((0.0, 0), (12.5, 0), (12.5, 1), (40.25, 1), (40.25, 0)):
        p.position[0] = x  # the head moves in X; Y, Z and B stand
        p.tool = tool
        f = status_fields(wire.raw(b"\xb0"))
        assert f["positions"] == fresh() and f["tool"] == b"%d" % tool
        reports.append(f["positions"])
    assert [r[0] for r in reports] == [nul8(0.0), nul8(12.5), nul8(12.5), nul8(40.25),
                                       nul8(40.25)]
    assert [r[3] for r in reports] == [nul8(0.0)] * 2 + [nul8(-0.0)] * 2 + [nul8(0.0)]
    assert nul8(-0.0) != nul8(0.0)
    assert status_fields(wire.raw(b"\xb0"))["extruders"] == b"10"
    head = wire.printer.hw.eeprom_bus.sockets[0]
    head.data = images.head_eeprom(False, "RBX01-DM")
    wire.fw.eeproms.initialise()  # (read again, as at power-up)
    wire.printer.settle()
    assert status_fields(wire.raw(b"\xb0"))["extruders"] == b"11"


def test_a_partial_command_waits_for_its_bytes(wire):
    wire.ok(b"\x97" + ident("part"))
    frame = b"\x91" + hexn(0, 8) + b"G" * 512
    wire.usb.host_write(frame[:300])
    wire.printer.run_until(lambda: False, 1.0)
    assert wire.usb.reply_waiting == 0
    assert wire.raw(frame[300:]) == b"\xe3" + b"0" * 64


def test_unknown_bytes_are_consumed_alone_and_set_bad_command(wire):
    wire.usb.host_write(b"\xb3")  # Robox mode
    wire.printer.run_until(lambda: wire.usb.reply_waiting > 0)
    wire.usb.host_read(65)
    wire.usb.host_write(b"\x80\x81zz")
    wire.printer.run_until(lambda: False, 0.1)
    assert wire.usb.reply_waiting == 0
    reply = wire.raw(b"\xb4")
    assert reply == b"\xe4r776sim\0"
    assert wire.ack(b"\xb3")[ErrorBit.BAD_COMMAND] == "1"


def test_a_command_takes_its_parameter_bytes_whatever_they_are(wire):
    wire.ok(b"\xb3")
    wire.usb.host_write(b"\x94abc\xb4")  # 4 of the 16 id bytes: the 0xb4 is one of them
    wire.printer.run_until(lambda: False, 0.1)
    assert wire.usb.reply_waiting == 0
    assert wire.raw(bytes(12))[0] == 0xE3  # the run-job command is complete now
    assert wire.ack(b"\xb3")[ErrorBit.USB_RX] == "0"


def test_replies_sent_back_to_back_all_arrive(wire):
    wire.ok(b"\xb3")
    wire.usb.host_write(b"\xb4\xbb")
    wire.printer.run_until(lambda: False, 0.05)
    assert wire.usb.host_read(64) == b"\xe4r776sim\0\xeb1"
    assert wire.ack(b"\xb3")[ErrorBit.USB_TX] == "0"


def test_pronterface_mode_lines_and_terminators(wire):
    assert wire.line(b"M115\r\n") == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
    assert wire.line(b"M115\n\r") == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
    assert wire.line(b"M115  \r") == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
    assert re.fullmatch(rb"S:\d+ @\d+ T:\d+ @\d+ B:\d+ \$\d+ A:\d+ \*\d+\r\nok\r\n",
                        wire.line(b"M105\n"))
    assert wire.line(b"G28 X Y ; home\n") == b"ok\r\n"
    assert wire.line(b"N12 G1 X10 Y5 F3000*87\n") == b"ok\r\n"
    assert wire.line(b"M400\n") == b"ok\r\n"
    job = wire.fw.job
    wire.printer.run_until(lambda: not job.execute_buffer and job.current is None
                           and wire.fw.motion.idle(), 10)
    # positions are where the whole steps queued end: within a step (1/133.7 mm) of 10, 5
    m114 = wire.line(b"M114\n")
    x, y = (float(word[2:]) for word in m114.split(b" ")[:2])
    assert x == pytest.approx(10.0, abs=1 / 133.7) and y == pytest.approx(5.0, abs=1 / 133.7)
    assert round(x * 133.7, 3).is_integer() and round(y * 133.7, 3).is_integer()
    assert m114.endswith(b" Z:0.000000 B:0.000000 T:0\r\nok\r\n")
    # G28 made Z safe first (3 mm up), so the Z switch is open
    assert wire.line(b"M119\n") == \
        b"M119 X:0 Y:0 Z:0 Z+:0 E:0 D:0 B:1 Eindex:1 Dindex:0\r\nok\r\n"
    assert wire.line(b"M999\n") == b"Bdelta:0.000000\r\nok\r\n"
    assert wire.line(b"X-unknown words\n") == b"ok\r\n"


def test_the_first_high_byte_switches_to_robox_mode_for_good(wire):
    assert wire.line(b"M115\n").startswith(b"FIRMWARE")
    assert wire.raw(b"\xb4")[0] == 0xE4
    wire.usb.host_write(b"M115\n")
    wire.printer.run_until(lambda: False, 0.1)
    assert wire.usb.reply_waiting == 0
    assert wire.ack(b"\xb3")[ErrorBit.BAD_COMMAND] == "1"


def test_gcode_over_0x95_reporting_and_queued(wire):
    assert wire.gcode(b"M115\r") == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
    assert wire.gcode(b"M115") == b""  # no terminator: no response
    assert wire.gcode(b"G1 X5 F600\r") == b""  # queued, not done
    # a reporting 0x95 runs its first line only; the rest is neither run nor queued
    # (recorded: 0x95 "M112\n..." answers b"Ydelta:0.000000\r\nok\r\n" alone)
    two = wire.gcode(b"M115\rM105\r")
    assert two == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
    assert not wire.fw.job.execute_buffer
    m503 = wire.gcode(b"M503\n")
    assert m503.startswith(b"Ver: ") and m503.endswith(b"ok\r\n")
    # show_parameters' own text: the factory settings, printed as C prints floats
    assert b"uSteps / Unit:\r\n  M92 X133.699997 Y133.699997 Z6400.000000 E747.000000 " \
        b"D747.000000 B2500.000000\r\n" in m503
    assert b"Nozzle:\r\n  M301 P8.000000e-02 I1.200000e-02 D5.500000e-01 B4380.000000 " \
        b"T19193.000000 U0\r\n" in m503
    assert b"Motor I (A):\r\n  M906 X1.093750 Y1.093750 Z0.937500 E1.328125 D1.328125 " \
        b"B10.078125\r\n" in m503
    assert m503.endswith(b"Filament slip thr (mm):\r\n  M909 S10.000000 T4.000000\r\nok\r\n")


def test_execute_buffer_overrun_drops_the_command(wire):
    wire.fw.job.execute_buffer += b"G4 S1000\r" * 3
    filler = b"G1 X1\r" * 169  # 1014 bytes: with its header, fits the receive buffer
    wire.gcode(filler)
    assert wire.ack(b"\xb3")[ErrorBit.GCODE_BUFFER_OVERRUN] == "1"
    assert len(wire.fw.job.execute_buffer) <= 1024


def test_file_list_and_send_file_report(wire):
    wire.upload("first", b"G28\r" * 200)
    wire.upload("macro", b"M104 S0\r", job=False)
    assert wire.raw(b"\x96") == b"\xe002" + ident("first") + ident("macro")
    assert wire.raw(b"\x93") == b"\xe9" + bytes(16) + b"00000000"
    wire.ok(b"\x97" + ident("next"))
    wire.ok(b"\x91" + hexn(0, 8) + b"G28\r" * 128)
    assert wire.raw(b"\x93") == b"\xe9" + ident("next") + b"00000001"
    assert wire.raw(b"\x96") == b"\xe001" + ident("first")  # the macro made way


def test_chunk_errors_are_acknowledged_with_their_bits(wire):
    wire.ok(b"\x97" + ident("seq"))
    errors = wire.ack(b"\x91" + hexn(3, 8) + b"x" * 512)
    assert errors[ErrorBit.CHUNK_SEQUENCE] == "1"


def test_format_sd_card(wire):
    wire.upload("first", b"G28\r")
    wire.ok(b"\xfe")
    assert wire.raw(b"\x96") == b"\xe000"


def test_leds_and_head_power(wire):
    wire.ok(b"\xc2" + b"ff8000")
    wire.ok(b"\xc5" + b"0000FF")
    machine = wire.printer.hw.machine
    assert machine.ambient_led == (255, 128, 0) and machine.button_led == (0, 0, 255)
    wire.ok(b"\xca1")
    assert machine.head_power


def test_reset_restarts_from_power_up_keeping_card_chips_and_flash(wire):
    wire.upload("keep", b"G28\r")
    wire.ok(b"\xc1" + b"ID".ljust(256, b"\0"))
    assert wire.fw.command.robox_mode
    assert wire.raw(b"\xfd") == b"\xe3" + b"0" * 64
    wire.printer.run_until(lambda: wire.fw.resets == 1, 1.0)
    assert wire.fw.resets == 1 and not wire.fw.command.robox_mode  # RAM started afresh
    assert wire.line(b"M115\n").startswith(b"FIRMWARE")
    assert wire.raw(b"\x96") == b"\xe001" + ident("keep")
    assert wire.raw(b"\xb2")[1:3] == b"ID"


# ------------------------------------------- hours counter (parameters.c)
def hours_page(wire) -> bytes:
    from robox.formats.firmware import HOURS_PAGE

    return wire.printer.hw.flash.page(HOURS_PAGE)


def test_a_job_adds_its_unpaused_run_time_to_the_hours_once_it_has_ended(wire):
    """maintain_hours_counter: ticks counted while the job runs and is not paused; one
    page write, "%f" of strtof(page) + ticks / 3.6e6 in float, once the job has ended
    and motion has stopped; the rest of the page zeroed by program_page."""
    wire.ok(b"\xc6" + b"12.50000")
    writes = wire.printer.hw.flash.page_writes
    wire.upload("hours", job_text(["G4 S20", "M1", "G4 S30"]))
    wire.ok(b"\x94" + ident("hours"))
    fw = wire.fw
    assert wire.printer.run_until(lambda: fw.job.paused(), 60)  # the job's own M1
    started = fw.hours.run_ticks
    wire.printer.run_until(lambda: False, 100)  # 100 s paused: not counted
    assert fw.hours.run_ticks == started
    assert wire.raw(b"\xb6") == b"\xea12.50000"  # nothing written while the job runs
    wire.ok(b"\x980")
    wire.wait_job_done()
    wire.printer.run_until(lambda: wire.printer.hw.flash.page_writes > writes, 1)
    text = wire.raw(b"\xb6")[1:]
    seconds = (float(text) - 12.5) * 3600
    assert 50 <= seconds < 51, text  # the dwells and the passes around them, not the pause
    assert hours_page(wire) == text + bytes(248)
    assert wire.printer.hw.flash.page_writes == writes + 1
    wire.printer.run_until(lambda: False, 30)
    assert wire.printer.hw.flash.page_writes == writes + 1  # the count starts again at 0


def test_hours_text_rounds_as_c_float_and_masks_on_reading(wire):
    import struct

    wire.ok(b"\xc6" + b"9999.999")
    wire.upload("h2", job_text(["G4 P7200"]))
    wire.ok(b"\x94" + ident("h2"))
    wire.wait_job_done()
    wire.printer.run_until(lambda: not wire.fw.hours.run_ticks, 1)
    ticks = 7200 + 0  # the dwell; the job's own passes add at most a few ticks
    text = wire.raw(b"\xb6")[1:]
    candidates = set()
    for extra in range(0, 20):
        f = struct.unpack("<f", struct.pack("<f", 9999.999))[0]
        t = struct.unpack("<f", struct.pack("<f", float(ticks + extra)))[0]
        total = struct.unpack("<f", struct.pack("<f", f + t / 3600000.0))[0]
        candidates.add(f"{total:f}"[:8].encode())
    assert text in candidates
    wire.ack(b"\xc6" + bytes([0xB1, 0xB2]) + b"345678")
    assert wire.raw(b"\xb6") == b"\xea12345678"  # get_hours_counter masks each byte
    assert hours_page(wire)[:2] == bytes([0xB1, 0xB2])


def test_a_power_cut_during_a_job_loses_its_hours(wire):
    wire.ok(b"\xc6" + b"1.000000")
    wire.upload("h3", job_text(["G4 S30"]))
    wire.ok(b"\x94" + ident("h3"))
    wire.printer.run_until(lambda: False, 10)
    assert wire.fw.hours.run_ticks > 9000
    wire.fw.power_up()
    wire.printer.run_until(lambda: False, 40)
    assert wire.raw(b"\xb6") == b"\xea1.000000"


def test_parameters_set_on_one_printer_leave_the_next_printers_factory_settings(wire):
    # the factory settings are worked out once; each power-up takes its own copy
    wire.gcode(b"M92 X80 E500\r")
    wire.gcode(b"M301 P0.5\r")
    changed = wire.gcode(b"M503\n")
    assert b"M92 X80.000000 Y133.699997" in changed and b"M301 P5.000000e-01" in changed
    from tests.firmware.wire import Wire
    fresh = Wire()
    fresh.printer.settle()
    m503 = fresh.gcode(b"M503\n")
    assert b"M92 X133.699997 Y133.699997 Z6400.000000 E747.000000 " in m503
    assert b"M301 P8.000000e-02 I1.200000e-02" in m503


def test_every_codes_parameter_length_is_its_fixed_length_or_its_headers_count():
    """The command object finds a command's length by its code from a table: for each
    of the 256 codes it is the code's fixed length, its header's count (the header
    incomplete until all of it is there) or unknown, as the firmware's own tables say."""
    from robox.firmware.command import (
        FIXED,
        HEADER_INCOMPLETE,
        UNKNOWN_CODE,
        VARIABLE,
        parameter_length,
    )

    for code in range(256):
        if code in FIXED:
            assert parameter_length(bytes([code])) == FIXED[code]
        elif code in VARIABLE:
            header, at, digits = VARIABLE[code]
            count = (0x1234 >> 4 * (4 - digits)) & ((1 << 4 * digits) - 1)
            raw = bytes([code]) + b"0" * at + b"%0*x" % (digits, count)
            raw = raw.ljust(1 + header, b"0")
            assert parameter_length(raw[:header]) == HEADER_INCOMPLETE
            assert parameter_length(raw) == header + count
        else:
            assert parameter_length(bytes([code])) == UNKNOWN_CODE
    # a few from the spec's table: a file chunk, a status request, a counted chunk end
    assert parameter_length(b"\x91") == 8 + 512
    assert parameter_length(b"\xb0") == 0
    assert parameter_length(b"\x92" + b"00000003" + b"0010") == 12 + 16
    assert parameter_length(b"\x80") == UNKNOWN_CODE


def test_the_link_takes_a_hosts_bytes_in_any_buffer_and_hands_out_bytes():
    """What a host writes crosses the link a packet of at most 64 bytes a frame, only
    to an armed read and no more than its room, in order across writes, and reaches
    the firmware, and the replies the host, as bytes."""
    from robox.hardware.usb import UsbLink

    link = UsbLink()
    data = bytes(range(200))
    link.host_write(data[:100])
    link.host_write(data[100:])
    assert link.peek(150) == data[:150] and link.received == 0
    link.arm(40)
    link.frame()
    link.frame()  # disarmed until the firmware takes what came
    assert link.received == 40
    taken = link.device_take(1000)
    assert type(taken) is bytes and taken == data[:40]
    got = b""
    while link.arriving:
        link.arm(1 << 20)
        link.frame()
        piece = link.device_take(1 << 20)
        assert len(piece) <= 64
        got += piece
    assert got == data[40:]
    link.device_send(b"\xe3" + b"0" * 64)
    assert link.host_read(10) == b"\xe3" + b"0" * 9
    assert type(link.host_read()) is bytes and not link.in_flight

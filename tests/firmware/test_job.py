"""The job engine over the wire: printing while uploading, resume, pause, abort, errors."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robox.firmware.gcode import IDLE_ABORT_S, IDLE_PAUSE_S, line_length
from robox.firmware.main import PASS_S
from robox.formats.protocol import JOB_LINE_LIMIT, ErrorBit
from robox.native import compiled_modules
from tests.firmware.test_protocol import status_fields
from tests.firmware.wire import circle_job, hexn, ident, job_text


def pause_char(wire) -> bytes:
    return wire.fw.job.state_text()[8:9]


def test_a_job_that_catches_up_with_its_upload_pauses_and_stays_paused(wire):
    data = circle_job(400)
    chunks = len(data) // 512
    wire.ok(b"\x97" + ident("circle"))
    for n in range(2):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    wire.ok(b"\x94" + ident("circle"))
    # the reader catches up with the writer: pausing ('1'), then paused and parked ('2')
    assert wire.printer.run_until(lambda: pause_char(wire) == b"2", 600)
    for n in range(2, chunks):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    tail = data[chunks * 512 :]
    wire.ok(b"\x92" + hexn(chunks, 8) + hexn(len(tail), 4) + tail)
    line = wire.fw.job.line_number
    wire.printer.run_until(lambda: False, 30)
    status = status_fields(wire.raw(b"\xb0"))
    assert status["pause"] == b"2" and status["job"] == ident("circle")  # still paused
    assert wire.fw.job.line_number == line
    assert wire.raw(b"\x96") == b"\xe001" + ident("circle")  # listed once complete
    wire.ok(b"\x980")  # the host resumes it
    wire.wait_job_done()
    assert ("job finished", ident("circle")) in wire.fw.events
    status = status_fields(wire.raw(b"\xb0"))
    assert status["job"] == bytes(16) and status["line"] == b"00000000"  # reset at the end
    assert status["nozzle0"][0] == b"0" and status["bed"][0] == b"0"  # heaters off
    assert status["nozzle0"][2] == b"210.0000"  # targets reloaded from the reel


@pytest.mark.skipif("robox.firmware.gcode" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_a_line_waiting_on_motion_is_resumed_only_once_it_can_go_on(wire):
    """A job line waiting for room in the motion queue, or for motion to end, is left
    suspended until it has what it waits for (resumed earlier, it would look and yield
    the same wait again), and the job prints to its end."""
    job, motion = wire.fw.job, wire.fw.motion
    drive = job._drive
    seen = []

    def watched():
        wait = job.waiting
        seen.append((wait.motion if wait is not None else None, motion.ready_for_more(),
                     motion.empty()))
        drive()

    job._drive = watched
    lines = job_text(["G4 P10", "M400", "G1 X10 Y10 F6000", "M400", "G4 P10"])
    wire.upload("waits", circle_job(150, heat=False) + lines)
    wire.ok(b"\x94" + ident("waits"))
    wire.wait_job_done()
    assert ("job finished", ident("waits")) in wire.fw.events
    ready = [s for s in seen if s[0] == "ready"]
    empty = [s for s in seen if s[0] == "empty"]
    assert len(ready) > 100 and len(empty) >= 2
    assert all(s[1] for s in ready) and all(s[2] for s in empty)


def _pass_by_pass(generator_lines: bool) -> list[tuple]:
    """A job, host lines sent while its lines wait on motion and an abort part-way, run
    pass by pass; the job engine's state after every pass. `generator_lines`: each
    buffered line run inside the generator that takes it off its buffer at its end
    (_buffer_line), rather than its own routine run as the step under way."""
    from tests.firmware.wire import Wire

    wire = Wire()
    wire.printer.settle()
    job, fw = wire.fw.job, wire.fw
    if generator_lines:
        action = job._action
        job._action = lambda direct=False: action(False)
    # (a line with no G, M or T has no routine: taken off at once)
    lines = job_text(["M400", "G4 P20", "; no code here"] * 3)
    wire.upload("lines", circle_job(60, heat=False) + lines + circle_job(60, heat=False))
    wire.ok(b"\x94" + ident("lines"))
    states = []
    sent = set()
    while job.running and len(states) < 100_000:
        at = job.line_number
        if at in (20, 60, 61) and at not in sent:  # host lines join the execute buffer
            sent.add(at)
            text = b"M106 S%d\r\n" % at
            wire.usb.host_write(b"\x95" + hexn(len(text), 4) + text)
        if at == 110 and at not in sent:
            sent.add(at)
            wire.usb.host_write(b"\xff")  # abort, a line under way
        fw.run_pass()
        states.append((fw.clock.now, job.line_number, job.lines_executed, job.job_buffer,
                       job.execute_buffer, job.current is None, job.running,
                       wire.usb.reply_waiting))
        if wire.usb.reply_waiting:
            wire.usb.host_read(1 << 16)
    return states


@pytest.mark.skipif("robox.firmware.gcode" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_a_buffered_line_run_as_the_step_under_way_leaves_its_buffer_as_the_generator_did():
    """The job engine runs a buffered line's own routine as its step (one generator
    fewer to resume at every pass a line waits) and takes the line off its buffer in the
    pass that routine ends: pass by pass, through lines that wait on motion, host lines
    joining the execute buffer and an abort, the state is the one the generator around
    each line leaves."""
    direct = _pass_by_pass(generator_lines=False)
    assert direct == _pass_by_pass(generator_lines=True)
    # and the run covered what it is for: lines waiting, host lines, the abort
    assert any(not s[5] for s in direct) and any(s[4] for s in direct)
    assert direct[-1][6] is False and any(s[6] for s in direct)


def test_a_heater_wait_looks_at_the_pass_after_it_begins(wire):
    """heaters.c waits `do { do_everything_else(); look } while (...)`: with the nozzle
    and the bed off, an M109 or M190 answers one pass later than an M104, not at the
    next moment the loop would stop for anyway (a heater's step, a quarter second on)."""
    def answered(text: bytes) -> float:
        start = wire.fw.clock.now
        assert wire.line(text) == b"ok\r\n"
        return wire.fw.clock.now - start

    plain = answered(b"M104 S0\n")
    for text in (b"M109 S0\n", b"M109\n", b"M190\n"):
        assert answered(text) == pytest.approx(plain + PASS_S)


def test_run_job_restarts_a_running_job_and_an_unknown_id_ends_it(wire):
    wire.upload("twice", job_text(["G4 S5"] * 20))
    wire.ok(b"\x94" + ident("twice"))
    wire.printer.run_until(lambda: wire.fw.job.line_number >= 3, 60)
    wire.ok(b"\x94" + ident("twice"))  # the running job starts again from its first line
    assert wire.fw.job.line_number == 0 and wire.fw.job.running
    wire.ok(b"\x94" + ident("nothing"))  # no such file: the read file closes
    status = status_fields(wire.raw(b"\xb0"))
    assert status["job"] == bytes(16)
    wire.printer.run_until(lambda: not wire.fw.job.running, 60)  # the G4 under way ends first
    assert not wire.fw.job.running


def test_the_line_number_in_the_status_report_counts_job_lines(wire):
    wire.upload("count", job_text(["G4 S30"] + ["G1 X1"] * 5 + ["G4 S1000"]), run_after=None)
    wire.ok(b"\x94" + ident("count"))
    wire.printer.run_until(lambda: wire.fw.job.line_number == 7, 200)
    assert status_fields(wire.raw(b"\xb0"))["line"] == b"00000007"


def test_run_job_with_an_empty_id_runs_the_last_job(wire):
    wire.upload("again", job_text(["G1 X5 F600"]))
    wire.ok(b"\x94" + ident("again"))
    wire.wait_job_done()
    wire.ok(b"\x94" + bytes(16))
    assert wire.fw.job.running and wire.fw.job.job_id == ident("again")


def test_an_interrupted_upload_resumes_from_the_send_file_report(wire):
    data = circle_job(300, heat=False)
    wire.ok(b"\x97" + ident("resume"))
    for n in range(5):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    wire.usb.disconnect()
    wire.usb.connect()
    report = wire.raw(b"\x93")
    assert report == b"\xe9" + ident("resume") + b"00000005"
    nxt = int(report[17:], 16)
    wire.ok(b"\x91" + hexn(3, 8) + b"x" * 512)  # a resent earlier chunk is ignored
    chunks = len(data) // 512
    for n in range(nxt, chunks):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    tail = data[chunks * 512 :]
    wire.ok(b"\x92" + hexn(chunks, 8) + hexn(len(tail), 4) + tail)
    assert wire.fw.file_system.read_committed(ident("resume")) == data


def test_pause_parks_resume_returns_and_the_job_finishes(wire):
    wire.upload("pausing", circle_job(200, heat=False))
    wire.ok(b"\x94" + ident("pausing"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 50, 100)
    wire.ok(b"\x981")
    states = {status_fields(wire.raw(b"\xb0"))["pause"]}
    wire.printer.run_until(lambda: pause_char(wire) == b"2", 100)
    states.add(status_fields(wire.raw(b"\xb0"))["pause"])
    assert b"2" in states and states <= {b"1", b"2"}  # pausing, then paused and parked
    line = wire.fw.job.line_number
    wire.printer.run_until(lambda: False, 60)
    assert wire.fw.job.line_number == line  # nothing runs while paused
    position = wire.fw.position
    parked_z = position.unpark_destination[2] + 2.0  # parked: Z lifted 2 mm
    assert position.destination[2] == pytest.approx(parked_z)
    assert float(wire.gcode(b"M114\r").split(b" ")[2][2:]) == pytest.approx(parked_z, abs=1e-3)
    wire.gcode(b"G91\rG1 Z1\rG90\r")  # jogging while paused runs from the execute buffer
    wire.ok(b"\x980")
    assert status_fields(wire.raw(b"\xb0"))["pause"] in (b"3", b"0")
    wire.wait_job_done()
    assert ("job finished", ident("pausing")) in wire.fw.events


def test_abort_stops_reading_at_once_and_ends_the_job_once_motion_stops(wire):
    wire.upload("abort", circle_job(300))
    wire.ok(b"\x94" + ident("abort"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 20, 600)
    wire.ok(b"\xff")
    job = wire.fw.job
    assert job.job_id is None and not job.execute_buffer and not job.job_buffer
    wire.printer.run_until(lambda: not job.running, 10)
    assert not job.running and not wire.fw.heaters.any_on() and wire.fw.motion.idle()
    status = status_fields(wire.raw(b"\xb0"))
    assert status["job"] == bytes(16) and status["line"] == b"00000000"


def test_a_latched_error_keeps_a_running_job_paused_until_cleared(wire):
    wire.upload("err", circle_job(300, heat=False))
    wire.ok(b"\x94" + ident("err"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.fw.errors.set(ErrorBit.B_STUCK)
    wire.printer.run_until(lambda: pause_char(wire) == b"2", 60)
    assert pause_char(wire) == b"2"
    wire.ack(b"\x980")
    wire.printer.run_until(lambda: False, 5)
    assert wire.fw.job.paused()  # the error is still latched: paused again
    wire.ack(b"\xc0")
    wire.ack(b"\x980")
    wire.printer.run_until(lambda: False, 5)
    assert not wire.fw.job.paused()


@pytest.mark.parametrize("bit", [ErrorBit.B_POSITION_WARNING, ErrorBit.E_NO_FILAMENT,
                                 ErrorBit.POWEROFF_WHILST_HOT])
def test_some_errors_never_pause(wire, bit):
    wire.upload("np", circle_job(300, heat=False))
    wire.ok(b"\x94" + ident("np"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.fw.errors.set(bit)
    wire.printer.run_until(lambda: False, 5)
    assert not wire.fw.job.paused()


def test_filament_slip_pauses_only_without_a_connected_host(wire):
    wire.upload("slip", circle_job(2000, heat=False))
    wire.ok(b"\x94" + ident("slip"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.ack(b"\xb3")  # an ack report: the host is connected for 5 s
    wire.fw.errors.set(ErrorBit.E_FILAMENT_SLIP)
    wire.printer.run_until(lambda: False, 2)
    assert not wire.fw.job.paused()
    wire.printer.run_until(lambda: wire.fw.job.paused(), 10)
    assert wire.fw.job.paused()


def test_a_line_longer_than_512_bytes_aborts_the_job(wire):
    # the buffer holds 1024 bytes: a line is too long once half of it holds no line end
    # (a 600-byte line can still fit, depending on where the block boundaries fall)
    wire.upload("long", job_text(["G1 X1", "G1 X2 " + ";" * 1100, "G1 X3"]))
    wire.ok(b"\x94" + ident("long"))
    wire.printer.run_until(lambda: not wire.fw.job.running, 30)
    assert wire.ack(b"\xb3")[ErrorBit.GCODE_LINE_TOO_LONG] == "1"
    assert wire.fw.job.line_number == 0  # the abort that ended the job reset it
    assert not wire.fw.position.homing_done[0]  # and G1 X3 never ran (nor moved anything)


def test_a_stalled_job_stays_paused_and_idle_heaters_go_off_after_an_hour(wire):
    wire.ok(b"\x97" + ident("stall"))
    wire.ok(b"\x91" + hexn(0, 8) + job_text(["M140 S60"] + ["G1 X1"] * 100)[:512])
    wire.ok(b"\x94" + ident("stall"))
    wire.printer.run_until(lambda: pause_char(wire) == b"2", 60)  # caught up: paused
    wire.printer.run_until(lambda: not wire.fw.job.running, IDLE_ABORT_S + 10)
    # the firmware only pauses a job for idleness, it never aborts one
    assert wire.fw.job.running and pause_char(wire) == b"2" and wire.fw.heaters.bed.mode
    wire.ok(b"\xff")
    wire.printer.run_until(lambda: False, 5)
    assert not wire.fw.job.running
    wire.gcode(b"M140 S60\r")
    wire.printer.run_until(lambda: wire.fw.heaters.bed.mode == 1, 10)
    start = wire.fw.clock.now
    wire.printer.run_until(lambda: wire.fw.heaters.bed.mode == 0, IDLE_ABORT_S + 10)
    assert wire.fw.heaters.bed.mode == 0  # no job, no activity for an hour: heaters off
    assert IDLE_ABORT_S - 1 <= wire.fw.clock.now - start < IDLE_ABORT_S + 10
    assert IDLE_PAUSE_S < IDLE_ABORT_S


def test_a_selfie_pause_from_the_job(wire):
    wire.upload("selfie", job_text(["G1 X10 F3000", "M1 C", "G1 X20"]))
    wire.ok(b"\x94" + ident("selfie"))
    wire.printer.run_until(lambda: pause_char(wire) == b"4", 60)
    assert status_fields(wire.raw(b"\xb0"))["pause"] == b"4"
    wire.ok(b"\x980")
    wire.wait_job_done()


def c_line_length(buffer: bytes) -> int:
    """get_gcode_line_length as gcode.c loops it, over a NUL-terminated copy."""
    line = bytes(buffer) + b"\0\0"
    i = 0
    while line[i] and line[i] not in b"\n\r":
        i += 1
    if not line[i]:
        return 0
    i += (line[i] == 0x0A and line[i + 1] == 0x0D) or (line[i] == 0x0D and line[i + 1] == 0x0A)
    i += 1
    while line[i] in b" \t" and line[i]:
        i += 1
    return i


@settings(max_examples=3000, deadline=None)
@given(st.binary(max_size=40) | st.lists(st.sampled_from([b"G1 X1", b"\r", b"\n", b"\0", b" ",
                                                           b"\t", b"M", b"\r\n", b"\n\r"]),
                                          max_size=12).map(b"".join))
def test_line_length_is_the_firmwares(buffer):
    assert line_length(buffer) == c_line_length(buffer)


def long_line_job(offset: int, length: int) -> bytes:
    """A job whose line of `length` bytes (before its CR) starts `offset` bytes in (after
    short lines)."""
    lead = []
    while offset:
        size = min(offset, 100) if offset - min(offset, 100) not in range(1, 8) else 50
        lead.append("M117 " + "a" * (size - 6))
        offset -= size
    return job_text([*lead, "M117 " + "b" * (length - 5), "G4 P1"])


@pytest.mark.parametrize("offset", [0, 8, 300, 505, 511, 512, 700, 1023])
def test_a_job_line_one_short_of_the_limit_prints_wherever_it_falls(wire, offset):
    """The host refuses job lines of JOB_LINE_LIMIT bytes or more (`send-job`): one byte
    less is read whole wherever it falls in the file's chunks."""
    wire.upload("long", long_line_job(offset, JOB_LINE_LIMIT - 1))
    wire.clear()
    wire.ok(b"\x94" + ident("long"))
    wire.wait_job_done()
    assert not wire.fw.errors.is_set(ErrorBit.GCODE_LINE_TOO_LONG)
    assert ("job finished", ident("long")) in wire.fw.events


def test_a_job_line_of_the_limit_at_the_start_of_a_file_aborts_the_job(wire):
    """Whether a longer line is read depends on where the reads of the card split it:
    at the start of the file, one of JOB_LINE_LIMIT bytes is not."""
    wire.upload("long", long_line_job(0, JOB_LINE_LIMIT))
    wire.clear()
    wire.ok(b"\x94" + ident("long"))
    wire.wait_job_done()
    assert wire.fw.errors.is_set(ErrorBit.GCODE_LINE_TOO_LONG)

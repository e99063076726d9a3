"""A job printed from its own upload pauses when it catches up with the writer and stays
paused (the real firmware's behaviour): the host resumes that pause, and only that one."""

import json
import time

import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from robox.cli import cli
from robox.formats.sdcard import make_id
from robox.gcode import prepare_job
from robox.host.client import CATCH_UP_CHECK_CHUNKS, catch_up_lines
from robox.sim.printer import VirtualPrinter
from tests.firmware.wire import job_text
from tests.host.test_client import connect
from tests.sim import serving


def fast_job(lines: int) -> bytes:
    """Lines that run at once (no heating, no motion): the reader soon catches up."""
    return prepare_job(job_text([f"M106 S{i % 250}" for i in range(lines)]))


@pytest.fixture
def virtual():
    v = VirtualPrinter()
    v.settle()
    return v


def test_catch_up_points_are_the_lines_of_whole_chunks():
    data = b"G90\r" * 300  # 4 bytes a line: 128 lines a chunk
    assert set(catch_up_lines(data)) == {128, 256}
    assert set(catch_up_lines(data, 1)) == {128}


def whole_chunk_lines(data: bytes) -> set[int]:
    """The lines complete at the end of each whole 512-byte chunk, counted afresh."""
    return {data[: 512 * k].count(b"\r") for k in range(1, len(data) // 512 + 1)}


class Stop(Exception):
    pass


def test_an_upload_returns_the_catch_up_points_it_counted_and_a_resumed_one_all(virtual):
    def job(pad: int) -> bytes:  # lines of uneven lengths: chunks end mid-line
        return b"".join(b"M106 S%d%s\r" % (i % 250, b" " * (i * pad % 37))
                        for i in range(900))

    first, second = job(1), job(5)
    assert len(first) % 512 and len(second) // 512 > 20
    printer = connect(virtual)
    sent = printer.send_file(first, "points", run=False)
    assert set(sent.catch_up) == whole_chunk_lines(first)

    def drop(done, total):
        if done >= 10 * 512:
            raise Stop  # the link goes once ten chunks are stored
    with pytest.raises(Stop):
        printer.send_file(second, "again", run=False, progress=drop)
    resumed = printer.send_file(second, "again", run=False, resume=True)
    assert resumed.first_chunk == 10 and not resumed.restarted
    assert set(resumed.catch_up) == whole_chunk_lines(second)
    assert virtual.firmware.file_system.read_committed(make_id("again")) == second


def test_send_file_resumes_the_pause_of_a_job_that_caught_up(virtual):
    job = fast_job(2000)
    printer = connect(virtual)
    seen = []
    notices = []

    def progress(done, total):
        # the upload is slow: the job prints everything stored, then pauses and parks
        virtual.run_until(lambda: False, 2.0)
        seen.append(virtual.firmware.job.state_text()[8:9])

    printer.send_file(job, "fast", progress=progress, notice=notices.append)
    assert b"2" in seen  # it did catch up, paused and parked
    assert printer.catch_up_resumes >= 1 and notices == []  # resumed; nothing else paused it
    fw = virtual.firmware
    assert virtual.run_until(lambda: not fw.job.running, 600)
    assert ("job finished", b"fast".ljust(16, b"\0")) in fw.events
    assert fw.job.lines_executed >= 2000


def test_an_upload_whose_job_prints_asks_for_the_status_every_few_chunks(virtual):
    """While its job prints, the upload looks for a catch-up pause every
    CATCH_UP_CHECK_CHUNKS chunks from the third on (the job starts with the second), and
    once more after the end: one status request (0xb0) each, and no others."""
    job = fast_job(8000)
    chunks = len(job) // 512
    printer = connect(virtual)
    frames: list[bytes] = []
    write = printer.transport.write
    printer.transport.write = lambda frame, timeout: (frames.append(frame[:1]),
                                                      write(frame, timeout))[1]
    printer.send_file(job, "polled")
    checks = [s for s in range(2, chunks) if s % CATCH_UP_CHECK_CHUNKS == 0]
    assert len(checks) >= 2
    assert frames.count(b"\xb0") == len(checks) + 1
    assert frames.count(b"\x91") == chunks


def test_a_pause_the_user_made_is_left_alone_and_reported(virtual):
    job = fast_job(3000)
    printer = connect(virtual)
    notices = []
    chunks_done = []

    def progress(done, total):
        chunks_done.append(done)
        virtual.run_until(lambda: False, 0.002)
        if len(chunks_done) == 3:
            printer.pause()  # the user's pause, mid-file
            virtual.run_until(lambda: False, 1.0)

    printer.send_file(job, "user", progress=progress, notice=notices.append)
    fw = virtual.firmware
    line = fw.job.line_number
    assert line not in catch_up_lines(job)
    virtual.run_until(lambda: False, 30)
    assert fw.job.running and fw.job.paused() and fw.job.line_number == line  # still paused
    assert notices and "left paused" in notices[0] and "by the user or the job" in notices[0]
    assert len(chunks_done) > CATCH_UP_CHECK_CHUNKS


def test_send_job_wait_over_a_pty_prints_a_job_that_catches_up(tmp_path):
    # long lines (five to a chunk) that run at once, on a printer paced to the wall: it
    # runs a line (about 100 bytes) a pass, where a chunk of 512 takes ten passes to
    # cross the bus, so the print outruns the upload on any host, as a real one would
    path = tmp_path / "fast.gcode"
    path.write_bytes(job_text([f"M106 S{i % 250}.{'0' * 90}" for i in range(600)]))
    with serving.served(tmp_path / "printer", speed=1) as pty:
        result = CliRunner().invoke(cli, ["--device", f"serial:{pty}", "send-job", str(path),
                                          "--wait", "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["lines"] == 600 and summary["errors"] == []
    assert summary["catch_up_resumes"] >= 1  # it did catch up, and was resumed


def test_a_run_for_a_host_stops_short_of_the_end_of_the_upload_its_job_prints(virtual):
    """With a reader margin, the served printer's run ends while the job printing its own
    upload still has that much of it to read; without one, the job reads to the end of
    what is stored and pauses (the catch-up)."""
    job = fast_job(2000)
    printer = connect(virtual)
    fs, seen = virtual.firmware.file_system, []

    def progress(done, total):
        if done == 512:  # the job starts with the second chunk: nothing reads it yet
            seen.append((fs.upload_length(), fs.upload_unread()))
        elif done == 4 * 512:
            seen.append((fs.upload_length(), done))
            virtual.run_for_host(5.0, reader_margin=1024)
            seen.append((fs.upload_unread(), virtual.firmware.job.pause))
            virtual.run_for_host(5.0)
            seen.append((fs.upload_unread(), virtual.firmware.job.pause))

    printer.send_file(job, "fast", progress=progress)
    assert seen[0] == (-1, -1)
    assert seen[1][0] == seen[1][1]  # stored so far: what the host has had acknowledged
    held, free = seen[2], seen[3]
    assert 0 <= held[0] < 1024 and held[1] == 0  # stopped short, still printing
    assert free == (0, 1)  # read to the end of what is stored, and paused
    assert fs.upload_length() == -1  # the upload is over


def test_send_job_wait_on_a_fast_served_printer_is_not_caught_up_by_its_print(tmp_path):
    # short lines (about 10 bytes) that run at once: a line a pass is slower than a chunk
    # every ten passes, so in real time the upload stays ahead; a clock running free
    # between the host's chunks (a second of printing at a time) would not keep it so
    lines = 6000
    path = tmp_path / "fast.gcode"
    path.write_bytes(job_text([f"M106 S{i % 250}" for i in range(lines)]))
    with serving.served(tmp_path / "printer") as pty:
        result = CliRunner().invoke(cli, ["--device", f"serial:{pty}", "send-job", str(path),
                                          "--wait", "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["lines"] == lines and summary["errors"] == []
    assert summary["catch_up_resumes"] == 0


def test_a_fast_served_job_catches_up_once_its_host_stops_sending(monkeypatch):
    """The clock waits for the host's next chunk only while the upload keeps growing: a
    host gone quiet mid-upload leaves the job to catch up and pause, as on the printer."""
    from robox.sim import serve

    monkeypatch.setattr(serve, "HOST_QUIET_S", 0.3)
    server = serve.PtyServer(VirtualPrinter(), None)
    fw = server.printer.firmware
    server.printer.settle()

    def ask(frame: bytes) -> bytes:
        return serving.ask(server, frame)[0]

    def serve_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            server.serve_once(timeout=0.01)

    job = fast_job(2000)
    try:
        assert ask(b"\x97" + make_id("quiet"))[0] == 0xE3
        for sequence in range(3):
            block = job[sequence * 512:(sequence + 1) * 512]
            assert ask(b"\x91" + f"{sequence:08x}".encode() + block)[0] == 0xE3
        assert ask(b"\x94" + make_id("quiet"))[0] == 0xE3
        serve_for(0.1)  # the host has just stored a chunk: the clock waits for the next
        assert fw.job.running and fw.job.pause == 0
        assert 0 <= fw.file_system.upload_unread() < serve.UPLOAD_MARGIN
        serve_for(0.5)  # the upload stopped growing 0.3 s ago: the job runs on and pauses
        assert fw.job.running and fw.job.pause == 1
        assert fw.file_system.upload_unread() == 0
    finally:
        server.close()
        server.printer.close()


_REPORT_JOB = st.one_of(st.just(b""), st.text("abcdefghijklmnopqrstuvwxyz0123456789_",
                                              min_size=1, max_size=16).map(str.encode))


@given(job=_REPORT_JOB, line=st.integers(0, 0xFFFFFFFF),
       pause=st.sampled_from(b"0123456789 ?"), rest=st.binary(min_size=196, max_size=196))
def test_a_progress_reads_a_report_s_job_line_and_pause(job, line, pause, rest):
    """What following a job reads of each poll: the job's name (bytes 1-16, NUL padded;
    none when empty), its line (bytes 17-24, hexadecimal) and the pause state (byte
    25), whatever the rest of the report holds; the whole Status reads them alike."""
    from robox.host.client import Progress, Status

    figures = bytes(b if 0x30 <= b <= 0x39 else 0x30 for b in rest)  # digits: parseable
    report = b"\xe1" + job.ljust(16, b"\0") + b"%08X" % line + bytes([pause]) + figures
    assert len(report) == 222
    states = {ord("0"): "running", ord("1"): "pausing", ord("2"): "paused",
              ord("3"): "resuming", ord("4"): "selfie pause"}  # the protocol's
    expected = (job.decode() or None, line, states.get(pause, "?"))
    assert Progress.of(report) == expected
    status = Status.parse(report)
    assert (status.job, status.line, status.pause) == expected


def test_a_printer_s_progress_is_its_status_job_line_and_pause(virtual):
    """Asked of the virtual printer with no job, printing one, and with the job paused
    (standing still: the status asked next is of the same moment)."""
    printer = connect(virtual)
    status = printer.status()
    assert printer.progress() == (status.job, status.line, status.pause) == \
        (None, 0, "running")
    printer.send_file(fast_job(3000), "progress", run=True)
    printing = printer.progress()
    assert printing.job == "progress" and printing.line > 0
    printer.transact(b"\x981")  # pause
    virtual.run_until(None, 30.0)
    paused, status = printer.progress(), printer.status()
    assert paused.pause == "paused" and paused.line >= printing.line
    assert paused == (status.job, status.line, status.pause)

"""A job's count of lines, its longest line and its SHA-1, taken as it is written, against
the same worked out afresh from the file's bytes."""

import hashlib

from hypothesis import given, settings
from hypothesis import strategies as st

from robox.formats.protocol import JOB_LINE_LIMIT
from robox.gcode.files import _write_job, job_file


def counted(data: bytes) -> tuple[int, int, str]:
    """Lines ended by a CR, the longest of them (the bytes after the last CR too) and
    the SHA-1, from the bytes."""
    parts = data.split(b"\r")
    return data.count(b"\r"), max(len(p) for p in parts), hashlib.sha1(data).hexdigest()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=12).map(lambda b: b.replace(b"\n", b"")), max_size=40),
       st.integers(min_value=0, max_value=4))
def test_what_is_counted_as_written_is_what_the_file_holds(tmp_path_factory, lines, repeat):
    # (repeated past 4096 lines, some examples are written in more than one batch)
    lines = lines * (1 + repeat * 1100)
    target = tmp_path_factory.mktemp("job") / "job.gcode"
    written = _write_job(iter(lines), target)
    data = target.read_bytes()
    assert data == b"".join(line + b"\r" for line in lines)
    if data:
        assert (written.lines, written.longest, written.digest.hexdigest()) == counted(data)
    else:
        assert (written.lines, written.longest) == (0, 0)


def test_a_line_holding_a_cr_is_two_of_the_cards_lines(tmp_path):
    target = tmp_path / "job.gcode"
    written = _write_job(iter([b"G28", b"M1\rcdefghij", b"G4 P1"]), target)
    assert (written.lines, written.longest) == (4, 8)  # "cdefghij", not the 11 given
    assert written.digest.hexdigest() == hashlib.sha1(target.read_bytes()).hexdigest()


def test_the_job_file_reports_the_bytes_it_holds(tmp_path):
    source = tmp_path / "part.gcode"
    long = b"M117 " + b"x" * (JOB_LINE_LIMIT - 5)
    source.write_bytes(b"; a slicer's\nG28 X Y\n" + b"G1 X1 Y2 F3000\n" * 5000 + long + b"\n"
                       + b"G4 P1\n")
    with job_file(source, None) as job:
        data = job.path.read_bytes()
        lines, longest, sha1 = counted(data)
        assert (job.lines, job.sha1, job.size) == (lines, sha1, len(data))
        assert longest == JOB_LINE_LIMIT
        assert job.long_line == (5002, JOB_LINE_LIMIT)  # G28, 5000 moves, then the M117

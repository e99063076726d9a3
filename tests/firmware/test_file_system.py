"""Behaviour of the file-system object, rule by rule from spec/sdcard.md."""

from dataclasses import replace

import pytest

from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.formats import sdcard as f
from robox.formats.protocol import ErrorBit
from robox.hardware.faults import FaultPlan
from robox.hardware.sdcard import SdCard
from tests.conftest import pattern, read_back, upload


def block0(card: SdCard) -> f.Directory:
    return f.Directory.decode(bytes(card.storage.data[:512]))


def ids(fs: FileSystem) -> list[bytes]:
    return [i.rstrip(b"\0") for i in fs.file_list()]


def test_a_blank_card_is_formatted_at_mount(card, fs):
    assert fs.file_list() == []
    raw = bytes(card.storage.data[:512])
    printer_format = f.Directory.fresh(3000).encode()
    # identical to a printer's format except the project's trailer in the padding
    assert raw[:44] == printer_format[:44] and raw[64:] == printer_format[64:]
    assert raw[44:48] == b"RBXd"


def test_upload_read_back_and_list_oldest_first(fs):
    a, b = pattern(5000, 1), pattern(512 * 3, 2)
    assert upload(fs, "alpha", a) and upload(fs, "beta", b, job=False)
    assert ids(fs) == [b"alpha", b"beta"]
    assert read_back(fs, "alpha") == a and read_back(fs, "beta") == b
    remounted = FileSystem(fs.card, ErrorFlags())
    assert read_back(remounted, "alpha") == a and ids(remounted) == [b"alpha", b"beta"]


def test_files_are_laid_end_to_end_from_block_one(card, fs):
    upload(fs, "a", pattern(1000, 1))
    upload(fs, "b", pattern(512, 2))
    d = block0(card)
    assert [(d.slots[i].start_block, d.slots[i].length) for i in d.ring()] == [(1, 1000), (3, 512)]
    assert d.next_write_block == 4


def test_send_file_report_follows_the_upload(fs):
    assert fs.send_file_report() == (bytes(16), 0)
    fs.start_write_file(b"job1", True)
    fs.write_chunk(0, pattern(512, 1))
    fs.write_chunk(1, pattern(512, 2))
    assert fs.send_file_report() == (b"job1".ljust(16, b"\0"), 2)
    fs.end_write_file(2, b"")
    assert fs.send_file_report() == (bytes(16), 0)


def test_sixteen_slots_hold_at_most_fifteen_files(fs):
    contents = {f"j{i}": pattern(600, i) for i in range(18)}
    for name, data in contents.items():
        assert upload(fs, name, data)
    assert ids(fs) == [f"j{i}".encode() for i in range(3, 18)]
    for i in range(3, 18):
        assert read_back(fs, f"j{i}") == contents[f"j{i}"]


def test_newest_non_job_is_deleted_when_the_next_upload_starts(fs):
    upload(fs, "job_a", pattern(700, 1))
    upload(fs, "macro", pattern(300, 2), job=False)
    upload(fs, "job_b", pattern(700, 3))
    assert ids(fs) == [b"job_a", b"job_b"]
    d = fs.directory
    assert d.slots[d.ring()[-1]].start_block == 3  # job_b reused the macro's space


def test_a_non_job_open_for_reading_is_not_deleted(fs):
    upload(fs, "macro", pattern(300, 2), job=False)
    assert fs.start_read_file("macro")
    upload(fs, "job_b", pattern(700, 3))
    assert ids(fs) == [b"macro", b"job_b"]


def test_a_new_file_starts_at_block_one_when_fewer_than_1024_blocks_remain(fs):
    upload(fs, "big", pattern(1500 * 512, 1))  # blocks 1..1500; 1500 remain after it
    upload(fs, "mid", pattern(600 * 512, 2))   # 1501..2100: 900 remain after it
    upload(fs, "small", pattern(512, 3))
    d = fs.directory
    starts = [d.slots[i].start_block for i in d.ring()]
    assert starts == [1501, 1]  # "big" was dropped when "small" took block 1
    assert ids(fs) == [b"mid", b"small"]


def test_a_file_wraps_past_the_end_and_the_oldest_files_make_room(fs):
    a, b = pattern(100 * 512, 1), pattern(2950 * 512, 2)
    upload(fs, "A", a)
    upload(fs, "B", b)
    d = fs.directory
    assert ids(fs) == [b"B"]  # B overran A's blocks, so A was dropped
    assert d.slots[d.ring()[0]].start_block == 101
    assert d.next_write_block == 52
    assert read_back(fs, "B") == b
    c = pattern(10 * 512, 3)
    upload(fs, "C", c)
    assert ids(fs) == [b"B", b"C"]
    # the spec's example: a printer's walk rejects this directory, ours keeps it
    assert not f.printer_walk(block0(fs.card), 3000).valid
    remounted = FileSystem(fs.card, ErrorFlags())
    assert ids(remounted) == [b"B", b"C"] and remounted.last_mount.action == "keep"
    assert read_back(remounted, "B") == b and read_back(remounted, "C") == c


def test_largest_file_fits_and_one_block_more_is_too_large(card, errors, fs):
    largest = (card.capacity - 2) * 512
    assert upload(fs, "max", pattern(largest, 1))
    assert read_back(fs, "max") == pattern(largest, 1)
    assert not upload(fs, "over", pattern(largest + 1, 2))
    assert errors.is_set(ErrorBit.FILE_TOO_LARGE)
    assert ids(fs) == []  # "max" was dropped making room, "over" never committed
    errors.clear()
    assert not fs.write_chunk(card.capacity, bytes(512))
    assert errors.is_set(ErrorBit.CHUNK_SEQUENCE)


def test_reading_a_job_while_it_is_still_being_written(fs):
    data = pattern(512 * 4 + 100, 9)
    fs.start_write_file("live", True)
    fs.write_chunk(0, data[:512])
    fs.write_chunk(1, data[512:1024])
    assert fs.start_read_file("live")
    assert fs.read() == data[:512] and fs.read() == data[512:1024]
    assert fs.read() == b"" and not fs.eof()  # caught up: nothing yet
    fs.write_chunk(2, data[1024:1536])
    assert fs.read() == data[1024:1536]
    fs.write_chunk(3, data[1536:2048])
    fs.end_write_file(4, data[2048:])
    assert fs.read() == data[1536:2048]
    assert fs.read() == data[2048:] and fs.eof()
    assert ids(fs) == [b"live"]


def test_a_job_opened_while_uploading_becomes_last_job_at_its_end(card, fs):
    upload(fs, "old", pattern(600, 1))
    fs.start_write_file("live", True)
    fs.write_chunk(0, pattern(512, 2))
    writes = card.writes
    assert fs.start_read_file("live")
    assert card.writes == writes  # the directory write waits for the end
    fs.end_write_file(1, b"tail")
    d = block0(card)
    assert d.slots[d.last_job].id.rstrip(b"\0") == b"live"


def test_the_oldest_file_being_read_is_clobbered_by_a_wrapping_upload(errors, fs):
    upload(fs, "first", pattern(1000 * 512, 1))
    upload(fs, "second", pattern(1000 * 512, 2))
    assert fs.start_read_file("first")
    assert fs.read()
    upload(fs, "third", pattern(900 * 512, 3))  # starts at 1: fewer than 1024 remain
    assert errors.is_set(ErrorBit.FILE_READ_CLOBBERED)
    assert fs.read() == b"" and fs.reading is None
    assert ids(fs) == [b"second", b"third"]


def test_reusing_the_slot_open_for_reading_clobbers_the_read(errors, fs):
    for i in range(15):
        upload(fs, f"j{i}", pattern(600, i))
    assert fs.start_read_file("j0")
    upload(fs, "j15", pattern(600, 15))  # ring full: j0 dropped, its slot is next
    assert not errors.is_set(ErrorBit.FILE_READ_CLOBBERED)
    assert fs.start_write_file("j16", True)
    assert errors.is_set(ErrorBit.FILE_READ_CLOBBERED) and fs.reading is None


def test_last_job_is_recorded_on_the_card_and_opened_by_an_empty_id(card, fs):
    upload(fs, "cube", pattern(700, 1))
    upload(fs, "vase", pattern(700, 2))
    upload(fs, "macro", pattern(70, 3), job=False)
    assert fs.start_read_file("cube")
    assert block0(card).last_job == 0
    assert fs.start_read_file("macro")  # a non-job is not a last job
    remounted = FileSystem(card, ErrorFlags())
    assert remounted.start_read_file(bytes(16))
    assert remounted.reading.rstrip(b"\0") == b"cube"


def test_no_last_job_means_the_empty_id_opens_nothing(fs):
    upload(fs, "cube", pattern(700, 1))
    assert not fs.start_read_file(b"")


def test_last_job_is_cleared_when_its_file_is_dropped(card, fs):
    upload(fs, "cube", pattern(1000 * 512, 1))
    fs.start_read_file("cube")
    fs.close()
    upload(fs, "big", pattern(2500 * 512, 2))
    assert ids(fs) == [b"big"] and block0(card).last_job == f.NO_JOB


def test_duplicate_ids_newest_wins(fs):
    upload(fs, "same", b"old content")
    upload(fs, "same", b"new content")
    assert ids(fs) == [b"same", b"same"]
    assert read_back(fs, "same") == b"new content"


def test_lookups_compare_all_sixteen_bytes(fs):
    upload(fs, b"abc", b"data")
    assert not fs.start_read_file(b"abc\0junk")
    assert fs.start_read_file(b"abc" + bytes(13))


def test_resent_chunks_are_ignored_and_gaps_are_refused(errors, fs):
    data = pattern(512 * 3, 4)
    fs.start_write_file("seq", True)
    fs.write_chunk(0, data[:512])
    assert fs.write_chunk(0, b"X" * 512)  # a resend: accepted, ignored
    assert not errors.bits
    assert not fs.write_chunk(2, data[1024:])
    assert errors.is_set(ErrorBit.CHUNK_SEQUENCE)
    fs.write_chunk(1, data[512:1024])
    assert not fs.end_write_file(1, b"")  # end with the wrong sequence number
    fs.write_chunk(2, data[1024:])
    assert fs.end_write_file(3, b"")
    assert read_back(fs, "seq") == data


def test_chunks_without_an_upload_are_out_of_sequence(errors, fs):
    assert not fs.write_chunk(0, bytes(512))
    assert errors.is_set(ErrorBit.CHUNK_SEQUENCE)


def test_a_zero_length_file_is_not_committed(card, fs):
    upload(fs, "keep", b"x")
    writes = card.writes
    assert upload(fs, "empty", b"")
    assert ids(fs) == [b"keep"] and card.writes == writes


def test_card_removal_drops_state_and_later_chunks_are_refused(card, errors, fs):
    upload(fs, "safe", pattern(900, 1))
    fs.start_write_file("cut", True)
    fs.write_chunk(0, pattern(512, 2))
    fs.start_read_file("safe")
    card.remove()
    fs.maintain()
    assert not fs.mounted
    assert not fs.write_chunk(1, pattern(512, 3))
    assert errors.is_set(ErrorBit.SD_CARD)
    card.insert()
    errors.clear()
    assert not fs.write_chunk(1, pattern(512, 3))
    assert errors.is_set(ErrorBit.CHUNK_SEQUENCE)
    assert ids(fs) == [b"safe"] and fs.reading is None
    assert read_back(fs, "safe") == pattern(900, 1)


def test_a_swapped_card_is_never_continued_silently(card, errors, fs):
    fs.start_write_file("cut", True)
    fs.write_chunk(0, pattern(512, 2))
    card.remove()
    card.insert()  # between two looks at the switch
    assert not fs.write_chunk(1, pattern(512, 3))
    assert errors.is_set(ErrorBit.CHUNK_SEQUENCE)


def test_every_access_without_a_card_sets_sd_card(card, errors, fs):
    card.remove()
    for call in (lambda: fs.file_list(), lambda: fs.start_read_file("x"),
                 lambda: fs.start_write_file("x", True), lambda: fs.format()):
        errors.clear()
        call()
        assert errors.is_set(ErrorBit.SD_CARD)


def test_a_read_error_is_retried_once_after_reinitialising(card, errors, fs):
    upload(fs, "f", pattern(1024, 1))
    fs.start_read_file("f")
    card.faults.failing_reads = {card.reads + 1}
    assert fs.read() == pattern(1024, 1)[:512]
    assert card.initialisations == 1 and not errors.bits


def test_a_second_read_failure_sets_sd_card_and_unmounts(card, errors, fs):
    upload(fs, "f", pattern(1024, 1))
    fs.start_read_file("f")
    card.faults.failing_reads = {card.reads + 1, card.reads + 2}
    assert fs.read() == b""
    assert errors.is_set(ErrorBit.SD_CARD) and not fs.mounted
    assert fs.file_list() == [b"f".ljust(16, b"\0")]  # the next access mounts again


def test_nonvolatile_bytes_survive_a_remount(card, fs):
    assert fs.set_nonvolatile(1, 1)
    assert bytes(card.storage.data[11:13]) == b"\0\x01"
    assert FileSystem(card, ErrorFlags()).nonvolatile(1) == 1


def test_format_drops_every_file(card, fs):
    upload(fs, "a", pattern(3000, 1))
    assert fs.format() and ids(fs) == []
    d = block0(card)
    assert (d.first_file, d.next_file, d.next_write_block, d.last_job) == (0, 0, 1, f.NO_JOB)


def printer_card(capacity: int, files: list[tuple[bytes, bool, bytes]], junk: bool) -> SdCard:
    """A card laid out as a printer writes it, built here without the file system."""
    card = SdCard.blank(capacity)
    d = f.Directory.fresh(capacity)
    if junk:  # bytes a printer keeps as read: padding, unused slot bytes, slots off the ring
        d = replace(d, padding=bytes(range(1, 52)))
        for i in range(f.SLOT_COUNT):
            d = d.with_slot(i, f.FileSlot(b"stale%d" % i + bytes(16 - len(b"stale%d" % i)),
                                          1, b"\x07\x08\x09", 999, 5))
    block = 1
    for index, (file_id, job, data) in enumerate(files):
        d = d.with_slot(index, f.FileSlot(file_id.ljust(16, b"\0"), int(job),
                                          b"\x07\x08\x09" if junk else bytes(3), block,
                                          len(data)))
        for offset in range(0, len(data), 512):
            card.storage.write((block + offset // 512) * 512,
                               data[offset : offset + 512].ljust(512, b"\0"))
        block += f.blocks_for(len(data))
    d = replace(d, next_file=len(files), next_write_block=block)
    card.storage.write(0, d.encode())
    return card


def test_a_printers_card_mounts_and_reads_back_byte_exact():
    files = [(b"cube", True, pattern(5000, 1)), (b"macro", False, pattern(100, 2))]
    card = printer_card(4096, files, junk=False)
    fs = FileSystem(card, ErrorFlags())
    assert fs.last_mount is None  # mounted on first use
    assert fs.file_list() and fs.last_mount.action == "keep"
    assert read_back(fs, "cube") == files[0][2] and read_back(fs, "macro") == files[1][2]


def test_our_writes_keep_the_bytes_a_printer_does_not_interpret():
    files = [(b"cube", True, pattern(5000, 1))]
    card = printer_card(4096, files, junk=True)
    fs = FileSystem(card, ErrorFlags())
    upload(fs, "vase", pattern(700, 2))
    d = block0(card)
    assert f.printer_walk(d, 4096).valid  # a printer keeps the card
    assert d.padding[:31] == bytes(range(1, 32))  # padding before the project's trailer
    assert d.slots[0].unused == b"\x07\x08\x09"
    assert d.slots[1].unused == bytes(3)  # a freshly started slot is zeroed
    assert all(d.slots[i].id.startswith(b"stale") for i in range(2, 16))


def test_an_inconsistent_next_write_block_never_overwrites_a_file():
    files = [(b"cube", True, pattern(5000, 1))]
    card = printer_card(4096, files, junk=False)
    d = replace(block0(card), next_write_block=3)  # inside "cube" (blocks 1..10)
    card.storage.write(0, d.encode())
    fs = FileSystem(card, ErrorFlags())
    fs.file_list()
    assert fs.last_mount.repairs
    upload(fs, "new", pattern(2000, 2))
    assert read_back(fs, "cube") == files[0][2]
    assert block0(card).slots[1].start_block == 11


def test_a_last_job_outside_the_ring_is_not_opened():
    files = [(b"cube", True, pattern(500, 1))]
    card = printer_card(4096, files, junk=False)
    card.storage.write(0, replace(block0(card), last_job=5).encode())
    fs = FileSystem(card, ErrorFlags())
    assert not fs.start_read_file(b"")


@pytest.mark.parametrize("recovery_copies", [True, False])
def test_behaviour_is_the_same_with_or_without_recovery_copies(recovery_copies):
    card = SdCard.blank(2048)
    fs = FileSystem(card, ErrorFlags(), recovery_copies=recovery_copies)
    for i in range(6):
        upload(fs, f"f{i}", pattern(300 * 512, i), job=i % 2 == 0)
    assert ids(fs) == [b"f0", b"f2", b"f4", b"f5"]


def test_format_of_a_card_a_printer_formatted_is_identical_but_for_the_trailer(card, fs):
    upload(fs, "a", pattern(3000, 1))
    fs.format()
    raw = bytes(card.storage.data[:512])
    fresh = f.Directory.fresh(card.capacity).encode()
    assert raw[:44] == fresh[:44] and raw[64:] == fresh[64:]


def test_maintain_without_removal_keeps_the_mount(fs):
    upload(fs, "a", b"x")
    fs.maintain()
    assert fs.mounted


def test_removal_during_a_directory_write_leaves_a_consistent_card(card, errors, fs):
    upload(fs, "a", pattern(3000, 1))
    card.faults = FaultPlan(remove_before_access=card._accesses + 3)
    upload(fs, "b", pattern(3000, 2))
    assert errors.is_set(ErrorBit.SD_CARD)
    card.insert()
    assert read_back(FileSystem(card, ErrorFlags()), "a") == pattern(3000, 1)

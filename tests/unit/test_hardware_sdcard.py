"""The simulated SD card: geometry, counters, card-detect and every injectable fault."""

import pytest

from robox.errors import CardAbsent, CardReadError, PowerCut
from robox.hardware.faults import FaultPlan, Tear
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import FileStorage, MemoryStorage


def test_capacity_comes_from_the_size_in_whole_kib():
    assert SdCard(MemoryStorage(bytes(2048 * 512 + 512))).capacity == 2048
    assert SdCard.blank(4096).capacity == 4096


def test_reads_and_writes_are_counted_and_land_at_block_offsets():
    card = SdCard.blank(2048)
    card.write_block(5, b"\x11" * 512)
    assert card.storage.data[5 * 512 : 6 * 512] == b"\x11" * 512
    assert card.read_block(5) == b"\x11" * 512
    assert card.read_blocks(4, 3) == bytes(512) + b"\x11" * 512 + bytes(512)
    assert (card.reads, card.writes) == (4, 1)


def test_out_of_range_and_short_writes_are_bugs_not_faults():
    card = SdCard.blank(2048)
    with pytest.raises(ValueError):
        card.read_block(2048)
    with pytest.raises(ValueError):
        card.write_block(1, b"short")


def test_power_cut_after_the_nth_write_lets_that_write_land():
    card = SdCard.blank(2048, FaultPlan(cut_after_write=2))
    card.write_block(1, b"a" * 512)
    with pytest.raises(PowerCut):
        card.write_block(2, b"b" * 512)
    assert card.storage.data[1024:1536] == b"b" * 512


def test_power_cut_is_not_an_exception_firmware_can_swallow():
    assert not issubclass(PowerCut, Exception)


def test_torn_write_prefix_lands_only_the_prefix():
    plan = FaultPlan(tear_write=1, tear=Tear(prefix=100))
    card = SdCard(MemoryStorage(b"\xee" * 2048 * 512), plan)
    with pytest.raises(PowerCut):
        card.write_block(3, b"\x01" * 512)
    block = bytes(card.storage.data[3 * 512 : 4 * 512])
    assert block == b"\x01" * 100 + b"\xee" * 412


def test_torn_write_mix_takes_each_byte_from_old_or_new():
    card = SdCard(MemoryStorage(b"\xee" * 2048 * 512), FaultPlan(tear_write=1, tear=Tear(seed=7)))
    with pytest.raises(PowerCut):
        card.write_block(3, b"\x01" * 512)
    block = bytes(card.storage.data[3 * 512 : 4 * 512])
    assert set(block) == {0x01, 0xEE}
    again = Tear(seed=7).apply(b"\xee" * 512, b"\x01" * 512)
    assert again == block  # the seed replays the same tear


def test_read_error_once_then_recovers():
    card = SdCard.blank(2048, FaultPlan(failing_reads={1}))
    with pytest.raises(CardReadError):
        card.read_block(0)
    card.initialise()
    assert card.read_block(0) == bytes(512)
    assert card.initialisations == 1


def test_card_removal_at_an_access_and_reinsertion():
    card = SdCard.blank(2048, FaultPlan(remove_before_access=2))
    card.read_block(0)
    with pytest.raises(CardAbsent):
        card.write_block(1, bytes(512))
    assert not card.present and card.writes == 0
    card.insert()
    assert card.present and card.insertions == 2
    card.write_block(1, bytes(512))


def test_file_storage_read_only_cannot_write(tmp_path):
    path = tmp_path / "card.img"
    path.write_bytes(bytes(2048 * 512))
    with FileStorage(path) as storage:
        card = SdCard(storage)
        assert card.read_block(0) == bytes(512)
        with pytest.raises(PermissionError):
            card.write_block(1, bytes(512))
    assert path.read_bytes() == bytes(2048 * 512)

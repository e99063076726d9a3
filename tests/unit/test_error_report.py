"""The 0xe3 report's 64 characters: written by the firmware's flags, read by the host."""

from hypothesis import given
from hypothesis import strategies as st

from robox.firmware.error_flags import ErrorFlags
from robox.formats.protocol import error_bits


@given(st.integers(0, 2**70))
def test_character_i_is_bit_i(bits):
    flags = ErrorFlags()
    flags.bits = bits
    report = flags.report()
    assert len(report) == 64
    for i in range(64):
        assert report[i] == (ord("1") if bits >> i & 1 else ord("0"))


@given(st.binary(min_size=0, max_size=80))
def test_the_host_reads_a_1_as_set_and_any_other_byte_as_clear(field):
    expected = 0
    for i, c in enumerate(field[:64]):
        if c == ord("1"):
            expected |= 1 << i
    assert error_bits(b"\xe3" + field) == expected


@given(st.integers(0, 2**64 - 1))
def test_a_report_reads_back_as_its_bits(bits):
    flags = ErrorFlags()
    flags.bits = bits
    assert error_bits(b"\xe3" + flags.report()) == bits


@given(st.lists(st.one_of(st.integers(0, 2**70), st.just(0),
                          st.sampled_from([1, 1 << 63, (1 << 64) | 1])), max_size=12))
def test_report_after_report_follows_every_change_of_the_bits(history):
    """One flags object reporting again and again (the report is kept while the bits
    stand): each report is the bits as they are then, character by character."""
    flags = ErrorFlags()
    for bits in [0, *history]:
        flags.bits = bits
        for _ in range(2):
            report = flags.report()
            assert report == bytes(ord("1") if bits >> i & 1 else ord("0")
                                   for i in range(64))

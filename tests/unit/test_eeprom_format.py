"""EEPROM bytes against values computed independently in the test."""

import ctypes
import ctypes.util
import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robox.errors import NotFoundError, UsageError
from robox.formats import eeprom as fmt
from robox.formats import float8


def reference_crc(data: bytes, register: int = 0x535E01FE) -> int:
    """Bit-by-bit reflected CRC-32 (0xEDB88320), no final XOR."""
    for byte in data:
        register ^= byte
        for _ in range(8):
            register = (register >> 1) ^ 0xEDB88320 if register & 1 else register >> 1
    return register


@given(st.binary(min_size=192, max_size=192))
def test_crc_matches_a_bitwise_reference_and_a_good_bank_ends_at_zero(data):
    assert fmt.eeprom_crc(data) == reference_crc(data)
    bank = fmt.bank_image(data)
    assert bank[192:] == struct.pack("<I", reference_crc(data))
    assert reference_crc(bank) == 0 and fmt.bank_good(bank)


def test_chip_image_layout():
    data = bytes(i % 128 for i in range(192))  # 7-bit, so masking leaves it as is
    chip = fmt.chip_image(data)
    crc = struct.pack("<I", reference_crc(data))
    assert chip[0x000:0x0C0] == data and chip[0x0C0:0x0C4] == crc
    assert chip[0x100:0x1C0] == data and chip[0x1C0:0x1C4] == crc
    assert chip[0x0C4:0x100] == b"\xff" * 60 and chip[0x1C4:] == b"\xff" * 60


def test_chip_image_masks_to_seven_bits():
    chip = fmt.chip_image(b"\xff" * 192)
    assert chip[:192] == b"\x7f" * 192


def test_the_loaded_bank_is_bank_0_then_bank_1_then_none():
    good = fmt.chip_image(b"A" * 192)
    assert fmt.loaded_bank(good) == 0
    bad0 = bytearray(good)
    bad0[5] ^= 1
    assert fmt.loaded_bank(bytes(bad0)) == 1
    bad0[0x105] ^= 1
    assert fmt.loaded_bank(bytes(bad0)) is None
    assert fmt.loaded_bank(b"\xff" * 512) is None and fmt.loaded_bank(bytes(512)) is None


@pytest.mark.parametrize("value,text", [
    (1.75, b"1.750000"), (240000.0, b"240000.0"), (-0.5, b"-0.50000"), (0.0, b"0.000000"),
    (12345678.0, b"12345678"), (210, b"210.0000"), (1e-7, b"0.000000"),
])
def test_float8_is_the_first_eight_characters_of_printf_f(value, text):
    assert float8.encode(value) == text
    assert float8.encode(value, b"\0") == text


def test_float8_pads_short_text():
    assert float8.encode(math.inf) == b"inf     "
    assert float8.encode(math.inf, b"\0") == b"inf\0\0\0\0\0"


@pytest.mark.parametrize("raw,value", [
    (b"1.750000", 1.75), (b" 1.5e2xy", 150.0), (b"abc", 0.0), (b"-.5     ", -0.5),
    (b"\0\0\0\0\0\0\0\0", 0.0), (b"12345678", 12345678.0), (b"+7", 7.0), (b"inf", math.inf),
])
def test_float8_parses_like_strtof(raw, value):
    assert float8.parse(raw) == value
    assert float8.parse(bytearray(raw)) == value  # a buffer's field read in place


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from([b"1.750000", b" 1.5e2xy", b"abc\0\0\0\0\0", b"-.5     ",
                                 b"\0" * 8, b"12345678", b"+7      ", b"inf     ",
                                 b"210.0000", b"-0.00000", b"nan     ", b"1.0e400 "]),
                max_size=8), st.integers(0, 9))
def test_a_run_of_fields_reads_as_each_field_alone(fields, start):
    """parse_fields (a status report's runs of figures) reads each field of a run as
    parse() reads it alone, wherever the run starts."""
    raw = b"#" * start + b"".join(fields) + b"tail"
    got = float8.parse_fields(raw, start, len(fields))
    want = [float8.parse(field) for field in fields]
    assert [struct.pack("<d", v) for v in got] == [struct.pack("<d", v) for v in want]


_LIBC = ctypes.util.find_library("c")


@pytest.mark.skipif(_LIBC is None, reason="needs the C library's strtod")
@settings(max_examples=3000, deadline=None)
@given(st.builds(lambda blank, sign, whole, point, frac, tail: blank + sign + whole + point
                 + frac + tail,
                 st.sampled_from([b"", b" ", b"\t ", b"\n"]), st.sampled_from([b"", b"-", b"+"]),
                 st.text("0123456789", max_size=10).map(str.encode),
                 st.sampled_from([b"", b"."]),
                 st.text("0123456789", max_size=10).map(str.encode),
                 st.sampled_from([b"", b"\0\0", b"  ", b"e3", b"E-2", b"x", b"-", b"."])))
def test_float8_reads_the_double_strtod_reads_then_rounds_it_to_a_float(raw):
    """Fields of up to 20 digits, a point anywhere, signs, blanks and what may follow
    (an exponent, NULs, junk): the C library's strtod, rounded to a float."""
    libc = ctypes.CDLL(_LIBC)
    libc.strtod.restype = ctypes.c_double
    libc.strtod.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
    expected = struct.unpack("<f", struct.pack("<f", libc.strtod(raw, None)))[0]
    got = float8.parse(raw)
    assert got == expected and math.copysign(1, got) == math.copysign(1, expected), raw


def test_float8_parses_to_float_precision():
    assert float8.parse(b"0.100000") == struct.unpack("<f", struct.pack("<f", 0.1))[0]


@given(st.floats(min_value=-9999999, max_value=99999999, allow_nan=False))
def test_float8_round_trips_within_its_precision(value):
    text = float8.encode(value)
    assert len(text) == 8
    back = float8.parse(text)
    digits = len(f"{value:f}".split(".")[0])
    assert abs(back - value) <= 10.0 ** (digits - 7) + abs(value) * 1e-7


def test_fits_refuses_integer_parts_longer_than_eight():
    assert float8.fits(99999999.0) and not float8.fits(123456789.0)
    assert not float8.fits(math.nan)
    with pytest.raises(UsageError):
        float8.encode_checked(-12345678.0)


SPEC_REEL = {"filament_id": (0x00, 16), "display_colour": (0x10, 6),
             "first_layer_nozzle_temperature": (0x28, 8), "nozzle_temperature": (0x30, 8),
             "first_layer_bed_temperature": (0x38, 8), "bed_temperature": (0x40, 8),
             "ambient_temperature": (0x48, 8), "filament_diameter": (0x50, 8),
             "filament_multiplier": (0x58, 8), "feed_rate_multiplier": (0x60, 8),
             "friendly_name": (0x68, 40), "material_type": (0x90, 1),
             "remaining_filament": (0xB8, 8)}
SPEC_HEAD = {"type_code": (0x00, 16), "unique_id": (0x10, 24), "max_temperature": (0x28, 8),
             "thermistor_beta": (0x30, 8), "thermistor_tcal": (0x38, 8),
             "nozzle0_x_offset": (0x40, 8), "nozzle0_y_offset": (0x48, 8),
             "nozzle0_z_offset": (0x50, 8), "nozzle0_b_offset": (0x58, 8),
             "nozzle1_x_offset": (0x70, 8), "nozzle1_y_offset": (0x78, 8),
             "nozzle1_z_offset": (0x80, 8), "nozzle1_b_offset": (0x88, 8),
             "nozzle1_last_filament_temperature": (0xA8, 8),
             "nozzle0_last_filament_temperature": (0xB0, 8), "head_hours": (0xB8, 8)}


@pytest.mark.parametrize("kind,table", [("reel", SPEC_REEL), ("head", SPEC_HEAD)])
def test_field_maps_are_the_specs_tables(kind, table):
    assert {n: (f.offset, f.size) for n, f in fmt.FIELDS[kind].items()} == table


def test_fields_are_written_and_read_by_name_leaving_other_bytes():
    data = bytearray(b"\x11" * 192)
    fmt.set_field(data, "reel", "filament_diameter", "1.75")
    fmt.set_field(data, "reel", "friendly_name", "Robox PLA")
    fmt.set_field(data, "reel", "display_colour", "#ff8000")
    assert data[0x50:0x58] == b"1.750000"
    assert data[0x68:0x90] == b"Robox PLA" + bytes(31)
    assert data[0x10:0x16] == b"FF8000" and data[0x16:0x28] == b"\x11" * 18
    assert data[0x58:0x68] == b"\x11" * 16
    values = fmt.fields_of("reel", data)
    assert values["filament_diameter"] == 1.75 and values["friendly_name"] == "Robox PLA"


@pytest.mark.parametrize("name,value,words", [
    ("filament_id", "x" * 17, "holds 16"), ("friendly_name", "caf\u00e9", "ASCII"),
    ("display_colour", "red", "colour"), ("remaining_filament", "123456789", "8 characters"),
    ("remaining_filament", "lots", "not a number"), ("material_type", "PL", "one character"),
])
def test_values_that_do_not_fit_are_refused(name, value, words):
    with pytest.raises(UsageError, match=words):
        fmt.set_field(bytearray(192), "reel", name, value)


def test_unknown_field_names_list_the_known_ones():
    with pytest.raises(NotFoundError, match="head_hours"):
        fmt.field("head", "nope")


def test_kind_is_guessed_from_a_head_type_code():
    assert fmt.guess_kind(b"RBX01-SM" + bytes(184)) == "head"
    assert fmt.guess_kind(b"RX123" + bytes(187)) == "head"
    assert fmt.guess_kind(b"PLA" + bytes(189)) == "reel"


def _f32(value: float) -> float:
    return struct.unpack("<f", struct.pack("<f", value))[0]


@pytest.mark.parametrize("written, stored", [
    ("2.85", b"2.850000"), ("1.75", b"1.750000"), ("0.1", b"0.100000"),
    ("240000", b"240000.0"), ("-0.05", b"-0.05000"), ("123.4567", b"123.4567"),
    ("0", b"0.000000")])
def test_a_float_field_is_shown_as_it_was_written(written, stored):
    data = bytearray(192)
    fmt.set_field(data, "reel", "filament_diameter", written)
    f = fmt.field("reel", "filament_diameter")
    assert f.raw(data) == stored  # the first 8 characters of C's %f
    read = fmt.fields_of("reel", bytes(data))["filament_diameter"]
    assert read == _f32(float(written))  # the printer's float32 ...
    shown = fmt.shown_fields("reel", bytes(data))["filament_diameter"]
    assert shown == float(written) and repr(shown) == repr(float(written))  # ... shown as written


@given(st.integers(0, 2**32 - 1))
def test_shortest_is_the_fewest_digits_that_give_the_same_float32(bits):
    value = struct.unpack("<f", struct.pack("<I", bits))[0]
    if not math.isfinite(value) or value == 0.0:
        return
    shown = float8.shortest(value)
    assert _f32(shown) == value
    digits = len(f"{shown:.9e}".split("e")[0].replace("-", "").replace(".", "").rstrip("0"))
    if digits > 1:  # one digit fewer gives another float32
        assert _f32(float(f"{value:.{digits - 1}g}")) != value

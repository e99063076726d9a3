"""Constants of the Robox USB protocol (spec/protocol.md)."""

from enum import IntEnum

#: Number of characters in the ack/errors report 0xe3 (one per error bit).
ERROR_REPORT_BITS = 64

#: A job read from the card is taken a line at a time from a 1024-byte buffer; once half
#: of it holds no line end, the printer latches GCODE_LINE_TOO_LONG and aborts the job.
#: So a job line has fewer bytes than this before its line end.
JOB_LINE_LIMIT = 512


class ErrorBit(IntEnum):
    """Error bits of the ack/errors report 0xe3; the value is the bit number."""

    SD_CARD = 0
    CHUNK_SEQUENCE = 1
    FILE_TOO_LARGE = 2
    GCODE_LINE_TOO_LONG = 3
    USB_RX = 4
    USB_TX = 5
    BAD_COMMAND = 6
    HEAD_EEPROM = 7
    BAD_FIRMWARE_FILE = 8
    FLASH_CHECKSUM = 9
    GCODE_BUFFER_OVERRUN = 10
    FILE_READ_CLOBBERED = 11
    MAX_GANTRY_ADJUSTMENT = 12
    REEL0_EEPROM = 13
    E_FILAMENT_SLIP = 14
    D_FILAMENT_SLIP = 15
    NOZZLE_FLUSH_NEEDED = 16
    Z_TOP_SWITCH = 17
    B_STUCK = 18
    REEL1_EEPROM = 19
    HEAD_POWER_EEPROM = 20
    HEAD_POWER_OVERTEMP = 21
    BED_THERMISTOR = 22
    NOZZLE0_THERMISTOR = 23
    NOZZLE1_THERMISTOR = 24
    B_POSITION_LOST = 25
    E_LOAD_SLIP = 26
    D_LOAD_SLIP = 27
    E_UNLOAD_SLIP = 28
    D_UNLOAD_SLIP = 29
    POWEROFF_WHILST_HOT = 30
    E_NO_FILAMENT = 31
    D_NO_FILAMENT = 32
    B_POSITION_WARNING = 33
    HEAD_SHORTED = 34
    X_DRIVER = 35
    Y_DRIVER = 36
    ZA_DRIVER = 37
    ZB_DRIVER = 38
    E_DRIVER = 39
    D_DRIVER = 40
    BED_TEMPERATURE_DROOP = 41


#: Errors that never pause a running job.
NEVER_PAUSE = frozenset({ErrorBit.B_POSITION_WARNING, ErrorBit.B_POSITION_LOST,
                         ErrorBit.POWEROFF_WHILST_HOT, ErrorBit.E_NO_FILAMENT,
                         ErrorBit.D_NO_FILAMENT})
#: Errors that do not pause a job while a host is connected (it asked for the ack/errors
#: report within the last 5 s).
NO_PAUSE_WHILE_CONNECTED = frozenset({ErrorBit.NOZZLE_FLUSH_NEEDED, ErrorBit.E_FILAMENT_SLIP,
                                      ErrorBit.D_FILAMENT_SLIP})
PAUSE_MASK = sum(1 << bit for bit in range(64) if bit not in NEVER_PAUSE)
PAUSE_MASK_CONNECTED = PAUSE_MASK & ~sum(1 << bit for bit in NO_PAUSE_WHILE_CONNECTED)


#: Words a person reads for each error bit.
ERROR_TEXT = {
    ErrorBit.SD_CARD: "SD card error",
    ErrorBit.CHUNK_SEQUENCE: "file chunk out of sequence",
    ErrorBit.FILE_TOO_LARGE: "file too large for the SD card",
    ErrorBit.GCODE_LINE_TOO_LONG: "G-code line too long",
    ErrorBit.USB_RX: "USB receive error",
    ErrorBit.USB_TX: "USB transmit error (reply clobbered)",
    ErrorBit.BAD_COMMAND: "unknown command",
    ErrorBit.HEAD_EEPROM: "head EEPROM not valid",
    ErrorBit.BAD_FIRMWARE_FILE: "bad firmware file",
    ErrorBit.FLASH_CHECKSUM: "flash checksum error",
    ErrorBit.GCODE_BUFFER_OVERRUN: "G-code buffer overrun",
    ErrorBit.FILE_READ_CLOBBERED: "file being read was overwritten",
    ErrorBit.MAX_GANTRY_ADJUSTMENT: "maximum gantry adjustment exceeded",
    ErrorBit.REEL0_EEPROM: "reel 0 EEPROM not valid",
    ErrorBit.E_FILAMENT_SLIP: "E filament slip",
    ErrorBit.D_FILAMENT_SLIP: "D filament slip",
    ErrorBit.NOZZLE_FLUSH_NEEDED: "nozzle flush needed",
    ErrorBit.Z_TOP_SWITCH: "Z top switch",
    ErrorBit.B_STUCK: "B axis stuck",
    ErrorBit.REEL1_EEPROM: "reel 1 EEPROM not valid",
    ErrorBit.HEAD_POWER_EEPROM: "head power off: EEPROM",
    ErrorBit.HEAD_POWER_OVERTEMP: "head power off: over temperature",
    ErrorBit.BED_THERMISTOR: "bed thermistor fault",
    ErrorBit.NOZZLE0_THERMISTOR: "nozzle 0 thermistor fault",
    ErrorBit.NOZZLE1_THERMISTOR: "nozzle 1 thermistor fault",
    ErrorBit.B_POSITION_LOST: "B position lost",
    ErrorBit.E_LOAD_SLIP: "E filament slipped while loading",
    ErrorBit.D_LOAD_SLIP: "D filament slipped while loading",
    ErrorBit.E_UNLOAD_SLIP: "E filament slipped while unloading",
    ErrorBit.D_UNLOAD_SLIP: "D filament slipped while unloading",
    ErrorBit.POWEROFF_WHILST_HOT: "powered off whilst hot",
    ErrorBit.E_NO_FILAMENT: "no E filament",
    ErrorBit.D_NO_FILAMENT: "no D filament",
    ErrorBit.B_POSITION_WARNING: "B position warning",
    ErrorBit.HEAD_SHORTED: "head shorted",
    ErrorBit.X_DRIVER: "X driver fault",
    ErrorBit.Y_DRIVER: "Y driver fault",
    ErrorBit.ZA_DRIVER: "ZA driver fault",
    ErrorBit.ZB_DRIVER: "ZB driver fault",
    ErrorBit.E_DRIVER: "E driver fault",
    ErrorBit.D_DRIVER: "D driver fault",
    ErrorBit.BED_TEMPERATURE_DROOP: "bed temperature droop",
}


# ---------------------------------------------------------------- framing
FIXED_REPLY_LENGTH = {0xE1: 222, 0xE2: 193, 0xE3: 65, 0xE4: 9, 0xE5: 257, 0xE6: 193,
                      0xE8: 193, 0xE9: 25, 0xEA: 9, 0xEB: 2, 0xEF: 257, 0xF0: 257, 0xFB: 257}
#: The report each command is answered with (every other command: the ack 0xe3).
REPLY_TO = {0x93: 0xE9, 0x95: 0xE7, 0x96: 0xE0, 0xA1: 0xE2, 0xA3: 0xE6, 0xA5: 0xE8,
            0xB0: 0xE1, 0xB2: 0xE5, 0xB4: 0xE4, 0xB6: 0xEA, 0xBB: 0xEB, 0xF0: 0xF0,
            0xFB: 0xFB, 0xFC: 0xEF}


def is_text(data: bytes) -> bool:
    """Whether `data` starts a text reply (a printer in Pronterface mode answers lines such
    as ``ok``): every report code is 0x80 or above, every text byte below."""
    return bool(data) and data[0] < 0x80


def reply_length(data: bytes) -> int | None:
    """Total length of the report that `data` starts, once enough of it says; None until
    then, and for text (`is_text`), which carries no length and ends when the printer falls
    quiet. ValueError for a byte that starts neither."""
    if not data or is_text(data):
        return None
    code = data[0]
    if code in FIXED_REPLY_LENGTH:
        return FIXED_REPLY_LENGTH[code]
    if code == 0xE0:
        return 3 + 16 * int(data[1:3], 16) if len(data) >= 3 else None
    if code == 0xE7:
        return 5 + int(data[1:5], 16) if len(data) >= 5 else None
    raise ValueError(f"{code:#04x} starts no report")


_ONES = bytes(0x31 if c == 0x31 else 0x30 for c in range(256))


def error_bits(ack: bytes) -> int:
    """The error bits of an ack/errors report (its 64 characters after the code)."""
    # '1' is a set bit; any other byte a clear one
    return int(bytes(ack[1:65]).translate(_ONES)[::-1] or b"0", 2)


def error_names(bits: int) -> list[str]:
    return [ERROR_TEXT[bit] for bit in ErrorBit if bits >> bit & 1]

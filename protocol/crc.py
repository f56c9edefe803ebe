"""CRC-8 SAE J1850 as used by AUTOSAR E2E profile 1 (poly 0x1D, init 0xFF, xor-out 0xFF).

The CRC of a frame covers the message's 16-bit Data ID (low byte, then high byte) followed by
bytes 1..DLC-1 of the frame (byte 0 holds the CRC itself). The register state after the two
Data ID bytes depends only on the message, so it is computed once per message (its "seed").
"""

from __future__ import annotations

POLY = 0x1D
INIT = 0xFF
XOR_OUT = 0xFF


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


TABLE: tuple[int, ...] = _make_table()


def seed_for_data_id(data_id: int) -> int:
    """Register state after feeding the Data ID's low and high byte from the initial value."""
    if not 0 <= data_id <= 0xFFFF:
        raise ValueError(f"data ID {data_id} does not fit in 16 bits")
    crc = TABLE[INIT ^ (data_id & 0xFF)]
    return TABLE[crc ^ (data_id >> 8)]


def crc8(seed: int, data: bytes | bytearray | memoryview, table: tuple[int, ...] = TABLE) -> int:
    """Finish the CRC over ``data`` from a register state ``seed`` (see :func:`seed_for_data_id`)."""
    crc = seed
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ XOR_OUT


def crc8_plain(data: bytes) -> int:
    """CRC-8 SAE J1850 of ``data`` alone (check value of b"123456789" is 0x4B)."""
    return crc8(INIT, data)

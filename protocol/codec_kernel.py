"""The codec's per-frame arithmetic over one message's layout (compiled: protocol/compiled.py).

:class:`Layout` holds what :mod:`protocol.codec` reads from the DBC for one message, as numbers;
:func:`decode` and :func:`encode` walk it: the CRC-8 over the payload from the message's seed,
the payload as one little-endian word, each signal's bits, its range, and its scaling. One source
runs interpreted or compiled; the arithmetic is the same in both (the scaling multiplies and adds
in doubles, the rounding of an encoded value is to nearest, ties to even: Python's ``round``,
C's ``rint``).
"""

from __future__ import annotations

import cython

if cython.compiled:
    from cython.cimports.libc.math import rint
else:
    rint = round

from array import array

from protocol.crc import TABLE, XOR_OUT

# C constants when compiled (cython.declare), module constants when interpreted
_XOR = cython.declare(cython.int, XOR_OUT)
#: decode's answers other than a record and a signal's index
WRONG_LENGTH, BAD_CRC = -2, -1
#: signal kinds
SCALED = cython.declare(cython.int, 0)
INTEGER = cython.declare(cython.int, 1)
CHOICE = cython.declare(cython.int, 2)
#: the columns of a layout's per-signal table
START = cython.declare(cython.Py_ssize_t, 0)
LENGTH = cython.declare(cython.Py_ssize_t, 1)
SIGNED = cython.declare(cython.Py_ssize_t, 2)
KIND = cython.declare(cython.Py_ssize_t, 3)
CHECK = cython.declare(cython.Py_ssize_t, 4)
RAW_MIN = cython.declare(cython.Py_ssize_t, 5)
RAW_MAX = cython.declare(cython.Py_ssize_t, 6)
SCALE = cython.declare(cython.Py_ssize_t, 7)
OFFSET = cython.declare(cython.Py_ssize_t, 8)
MINIMUM = cython.declare(cython.Py_ssize_t, 9)
MAXIMUM = cython.declare(cython.Py_ssize_t, 10)
COLUMNS = cython.declare(cython.Py_ssize_t, 11)

_TABLE = bytes(TABLE)  # the CRC table as bytes: a C array of unsigned char when compiled
_new = tuple.__new__


@cython.cclass
class Layout:
    """One message's layout: DLC, CRC seed, the record type, the enumerations, and per signal one
    row of ``COLUMNS`` numbers (its bits, signedness, kind, whether its raw range is narrower than
    its bits', that range, the scaling and the physical range) in one flat table of doubles (every
    integer in it is exact in a double)."""

    dlc: cython.Py_ssize_t
    seed: cython.int
    n: cython.Py_ssize_t
    record: object
    choices: tuple  # per signal: the frozenset of its enumerated raw values, or None
    table: cython.double[::1]

    def __init__(self, dlc, seed, record, choices, table) -> None:
        if len(table) != len(choices) * COLUMNS or dlc < 2:  # the kernel reads both unchecked
            raise ValueError(f"a layout of {len(choices)} signals needs {len(choices) * COLUMNS} numbers and a DLC of 2 or more")
        self.dlc, self.seed, self.n, self.record, self.choices, self.table = dlc, seed, len(choices), record, choices, table


def layout_of(spec) -> Layout:
    """The layout of a :class:`protocol.catalog.MessageSpec`."""
    table = array("d")  # a buffer for the compiled kernel, Python floats for the interpreted one
    for s in spec.signals:
        kind = CHOICE if s.choices is not None else INTEGER if s.is_integer else SCALED
        narrower = (s.raw_min, s.raw_max) != (s.raw_min_representable, s.raw_max_representable)
        row = (s.start, s.length, s.signed, kind, narrower, s.raw_min, s.raw_max, s.scale, s.offset, s.minimum, s.maximum)
        assert len(row) == COLUMNS and all(abs(int(x)) < 2**53 for x in row[:7])  # exact as doubles
        table.extend([float(x) for x in row])
    choices = tuple(frozenset(s.choices) if s.choices is not None else None for s in spec.signals)
    return Layout(spec.dlc, spec.crc_seed, spec.record, choices, table)


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(k=cython.Py_ssize_t, i=cython.Py_ssize_t, row=cython.Py_ssize_t, dlc=cython.Py_ssize_t, c=cython.int,
               word=cython.ulonglong, u=cython.ulonglong, r=cython.longlong, length=cython.int, one=cython.ulonglong,
               kind=cython.int, crc=cython.p_uchar, d=cython.p_uchar, sig=cython.double[::1], values=list)
def decode(layout: Layout, data):
    """The record of ``data`` (bytes or bytearray), or why not: ``WRONG_LENGTH`` for a length
    other than the message's DLC, ``BAD_CRC``, or the index of the first signal outside its range
    or enumeration."""
    dlc = layout.dlc
    if len(data) != dlc:
        return WRONG_LENGTH
    crc, d = _TABLE, data
    c = crc[layout.seed ^ d[1]]
    for i in range(2, dlc):
        c = crc[c ^ d[i]]
    if c ^ _XOR != d[0]:
        return BAD_CRC
    sig = layout.table
    word, one = 0, 1
    for i in range(dlc - 1, -1, -1):
        word = (word << 8) | d[i]
    values = []
    for k in range(layout.n):
        row = k * COLUMNS
        length = cython.cast(cython.int, sig[row + LENGTH])
        u = (word >> cython.cast(cython.int, sig[row + START])) & ((one << length) - 1)
        if sig[row + SIGNED] != 0.0 and (u >> (length - 1)) & 1:
            r = cython.cast(cython.longlong, u) - cython.cast(cython.longlong, one << length)
        else:
            r = cython.cast(cython.longlong, u)
        kind = cython.cast(cython.int, sig[row + KIND])
        if kind == CHOICE:
            if r not in layout.choices[k]:
                return k
            values.append(r)
            continue
        if sig[row + CHECK] != 0.0 and not sig[row + RAW_MIN] <= r <= sig[row + RAW_MAX]:
            return k
        if kind == INTEGER:
            values.append(r)
        elif sig[row + OFFSET] != 0.0:
            values.append(r * sig[row + SCALE] + sig[row + OFFSET])
        else:
            values.append(r * sig[row + SCALE])
    return _new(layout.record, values)


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(k=cython.Py_ssize_t, i=cython.Py_ssize_t, row=cython.Py_ssize_t, dlc=cython.Py_ssize_t, c=cython.int,
               word=cython.ulonglong, raw=cython.longlong, one=cython.ulonglong, v=cython.double, kind=cython.int,
               crc=cython.p_uchar, p=cython.p_uchar, out=bytearray, sig=cython.double[::1], vals=tuple)
def encode(layout: Layout, values, counter: cython.int):
    """The payload of ``values`` (a sequence in signal order) with the alive ``counter`` (bits 8..11)
    and the CRC (byte 0), or the index of the first value outside its range or enumeration."""
    crc, dlc, sig, vals = _TABLE, layout.dlc, layout.table, tuple(values)
    if len(vals) != layout.n:  # the loop reads vals unchecked
        raise ValueError(f"expected {layout.n} values, got {len(vals)}")
    word, one = counter & 0xF, 1
    for k in range(layout.n):
        row = k * COLUMNS
        kind = cython.cast(cython.int, sig[row + KIND])
        if kind == CHOICE:
            if vals[k] not in layout.choices[k]:
                return k
            raw = int(vals[k])
        else:
            v = vals[k]
            if not sig[row + MINIMUM] <= v <= sig[row + MAXIMUM]:  # also False for NaN
                return k
            if kind == INTEGER:
                raw = cython.cast(cython.longlong, v)  # toward zero, as int()
            elif sig[row + OFFSET] != 0.0:
                raw = cython.cast(cython.longlong, rint((v - sig[row + OFFSET]) / sig[row + SCALE]))
            else:
                raw = cython.cast(cython.longlong, rint(v / sig[row + SCALE]))
        if sig[row + SIGNED] != 0.0:
            raw &= cython.cast(cython.longlong, (one << cython.cast(cython.int, sig[row + LENGTH])) - 1)
        word |= cython.cast(cython.ulonglong, raw) << (cython.cast(cython.int, sig[row + START]) - 8)
    out = bytearray(dlc)
    p = out
    c = layout.seed
    for i in range(1, dlc):
        p[i] = word & 0xFF
        word >>= 8
        c = crc[c ^ p[i]]
    p[0] = c ^ _XOR
    return bytes(out)

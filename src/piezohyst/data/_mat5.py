"""A structural check of MATLAB v5/v7 files before scipy reads them.

scipy's compiled v5 reader trusts the file: an element whose type code is out of range (found by
fuzzing damaged files: a single flipped byte) crashes the interpreter with a segmentation fault,
which no ``try`` can catch. This walks every element tag, decompressing ``miCOMPRESSED``
variables (bounded by the memory limit), and refuses what is not a well-formed file: unknown
element types, byte counts that overrun their container or disagree with the array's size,
negative dimensions, structs and cells whose element counts do not add up. It also totals the
arrays' sizes, structs and cells included, for the memory check.

Format: "MATLAB 5.0 MAT-File Format" (The MathWorks, matfile_format.pdf): a 128-byte header
(endian mark "IM" at byte 126), then data elements, each an 8-byte tag (type, byte count) or a
4-byte "small element" tag with up to 4 bytes of data; inside an ``miMATRIX`` the sub-elements
are array flags, dimensions, name, then the class's data, each padded to 8 bytes.
"""

from __future__ import annotations

import math
import struct
import zlib

ITEM = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8, 16: 1, 17: 2, 18: 4}
MATRIX, COMPRESSED = 14, 15
NUMERIC = set(range(6, 16))  # double, single, int8 ... uint64
CELL, STRUCT, OBJECT, CHAR, SPARSE, FUNCTION, OPAQUE = 1, 2, 3, 4, 5, 16, 17
MAX_DEPTH = 64


class Malformed(ValueError):
    """Where and how the file departs from the format (the caller adds the file name)."""


def check(data: bytes, limit: int) -> int:
    """Check a whole v5 file; return the bytes its arrays take once read (float64 where numeric)."""
    if len(data) < 128:
        raise Malformed("shorter than the 128-byte MATLAB header")
    mark = data[126:128]
    if mark not in (b"IM", b"MI"):
        raise Malformed("no endian mark in the MATLAB header")
    order = "<" if mark == b"IM" else ">"
    total = 0
    pos = 128
    while pos < len(data):
        if len(data) - pos < 8:
            raise Malformed(f"cut off at byte {pos}")
        typ, n = struct.unpack(order + "II", data[pos:pos + 8])
        start, end = pos + 8, pos + 8 + n
        if end > len(data):
            raise Malformed(f"the variable at byte {pos} runs past the end of the file")
        if typ == COMPRESSED:
            inner = _inflate(data[start:end], limit, pos)
            if len(inner) < 8:
                raise Malformed(f"the compressed variable at byte {pos} is empty")
            ityp, inn = struct.unpack(order + "II", inner[:8])
            if ityp != MATRIX or 8 + inn > len(inner):
                raise Malformed(f"the compressed variable at byte {pos} does not hold an array")
            total += _matrix(inner[8:8 + inn], order, 1, pos)
        elif typ == MATRIX:
            total += _matrix(data[start:end], order, 1, pos)
        else:
            raise Malformed(f"element type {typ} at byte {pos} where a variable should start")
        if total > limit:
            return total
        pos = end
    return total


def _inflate(blob: bytes, limit: int, at: int) -> bytes:
    d = zlib.decompressobj()
    try:
        out = d.decompress(blob, max(1, limit))
    except zlib.error as exc:
        raise Malformed(f"the compressed variable at byte {at} is damaged ({exc})") from None
    if d.unconsumed_tail:
        raise Malformed(f"the compressed variable at byte {at} unpacks to more than the memory limit")
    return out


def _elements(buf: bytes, order: str, at: int) -> list[tuple[int, bytes]]:
    """The sub-elements of an miMATRIX: (type, data), padding skipped."""
    out = []
    pos = 0
    while pos < len(buf):
        if len(buf) - pos < 8:
            if buf[pos:].strip(b"\x00"):
                raise Malformed(f"a cut-off element in the array at byte {at}")
            break
        word, n = struct.unpack(order + "II", buf[pos:pos + 8])
        small = word >> 16
        if small:  # small data element: type in the low half, count in the high half, data in n's place
            typ, count = word & 0xFFFF, small
            if count > 4:
                raise Malformed(f"a small element of {count} bytes in the array at byte {at}")
            _known(typ, at)
            out.append((typ, buf[pos + 4:pos + 4 + count]))
            pos += 8
            continue
        _known(word, at)
        end = pos + 8 + n
        if end > len(buf):
            raise Malformed(f"an element of {n} bytes overruns the array at byte {at}")
        out.append((word, buf[pos + 8:end]))
        pos = end + ((8 - n % 8) % 8 if word != MATRIX else 0)
    return out


def _known(typ: int, at: int) -> None:
    if typ not in ITEM and typ != MATRIX:
        raise Malformed(f"unknown element type {typ} in the array at byte {at}")


def _data(el: tuple[int, bytes], numel: int, at: int, what: str) -> None:
    typ, body = el
    if typ not in ITEM or len(body) != numel * ITEM[typ]:
        raise Malformed(f"the {what} of the array at byte {at} holds {len(body)} bytes for {numel} values")


def _matrix(buf: bytes, order: str, depth: int, at: int) -> int:
    """Check one miMATRIX body; return its size once read."""
    if depth > MAX_DEPTH:
        raise Malformed(f"arrays nested more than {MAX_DEPTH} deep")
    if not buf:
        return 0  # an empty element of a cell
    els = _elements(buf, order, at)
    if len(els) < 3 or els[0][0] != 6 or len(els[0][1]) != 8 or els[1][0] != 5 or len(els[1][1]) % 4 \
            or len(els[1][1]) < 8 or els[2][0] not in (1, 2):
        raise Malformed(f"the array at byte {at} lacks its flags, dimensions or name")
    flags = struct.unpack(order + "II", els[0][1])[0]
    cls = flags & 0xFF
    is_complex = bool(flags & 0x800)
    dims = struct.unpack(order + f"{len(els[1][1]) // 4}i", els[1][1])
    if any(d < 0 for d in dims):
        raise Malformed(f"the array at byte {at} has negative dimensions {dims}")
    numel = math.prod(dims)
    rest = els[3:]
    if cls in NUMERIC:
        if not rest:
            raise Malformed(f"the array at byte {at} has no data")
        _data(rest[0], numel, at, "real part")
        if is_complex:
            if len(rest) < 2:
                raise Malformed(f"the complex array at byte {at} has no imaginary part")
            _data(rest[1], numel, at, "imaginary part")
        return numel * 8 * (2 if is_complex else 1)
    if cls == CHAR:
        if rest and rest[0][0] not in ITEM:
            raise Malformed(f"the text at byte {at} has a bad type")
        return numel * 4
    if cls == CELL:
        return _nested(rest, numel, order, depth, at)
    if cls in (STRUCT, OBJECT):
        if cls == OBJECT:
            if not rest or rest[0][0] not in (1, 2):
                raise Malformed(f"the object at byte {at} has no class name")
            rest = rest[1:]
        if len(rest) < 2 or rest[0][0] != 5 or len(rest[0][1]) != 4 or rest[1][0] not in (1, 2):
            raise Malformed(f"the struct at byte {at} lacks its field names")
        width = struct.unpack(order + "i", rest[0][1])[0]
        if width <= 0 and rest[1][1]:
            raise Malformed(f"the struct at byte {at} has field names of width {width}")
        nfields = len(rest[1][1]) // width if width > 0 else 0
        if width > 0 and len(rest[1][1]) % width:
            raise Malformed(f"the struct at byte {at} has field names that do not fill their width")
        return _nested(rest[2:], numel * nfields, order, depth, at)
    if cls == SPARSE:
        if len(rest) < 3 or rest[0][0] != 5 or rest[1][0] != 5 or rest[2][0] not in ITEM:
            raise Malformed(f"the sparse array at byte {at} is incomplete")
        return sum(len(b) for _t, b in rest) * 2
    if cls in (FUNCTION, OPAQUE):
        size = 0
        for typ, body in rest:
            size += _matrix(body, order, depth + 1, at) if typ == MATRIX else len(body)
        return size
    raise Malformed(f"the array at byte {at} has an unknown class {cls}")


def _nested(rest: list[tuple[int, bytes]], count: int, order: str, depth: int, at: int) -> int:
    if len(rest) != count or any(t != MATRIX for t, _b in rest):
        raise Malformed(f"the cell or struct at byte {at} holds {len(rest)} arrays where its size says {count}")
    return sum(_matrix(b, order, depth + 1, at) for _t, b in rest)

"""Independent MATLAB v5 reader for the tests: prints the named numeric variables of a .mat file
as JSON {name: {"dims": [rows, cols, ...], "data": [column-major values]}}.

Written from MathWorks' "MAT-File Format" (Level 5): a 128-byte header, then data elements
(type, size, data padded to 8 bytes; a "small" element packs size and type in one word);
miCOMPRESSED (15) holds a zlib stream of one element; miMATRIX (14) holds array flags,
dimensions, name and the real part. Only real numeric arrays are printed (no kfuse code).
Usage: python3 mat5_values.py FILE NAME...
"""
import json
import struct
import sys
import zlib

NUMERIC = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 9: "d", 12: "q", 13: "Q"}
NUMERIC_CLASSES = set(range(6, 16))  # mxDOUBLE_CLASS .. mxUINT64_CLASS


def element(buf, pos):
    """(type, payload, next position) of the data element at pos."""
    typ, size = struct.unpack_from("<II", buf, pos)
    if typ >> 16:  # small data element: size in the upper half, data in the next 4 bytes
        return typ & 0xFFFF, buf[pos + 4 : pos + 4 + (typ >> 16)], pos + 8
    data = buf[pos + 8 : pos + 8 + size]
    if typ == 15:  # compressed: not padded
        return typ, data, pos + 8 + size
    return typ, data, pos + 8 + size + (-size % 8)


def values(typ, data):
    fmt = NUMERIC[typ]
    n = len(data) // struct.calcsize(fmt)
    return list(struct.unpack("<%d%s" % (n, fmt), data[: n * struct.calcsize(fmt)]))


def matrix(data):
    _, flags, p = element(data, 0)
    cls = struct.unpack_from("<I", flags)[0] & 0xFF
    _, dims, p = element(data, p)
    _, name, p = element(data, p)
    name = name.decode("latin-1")
    if cls not in NUMERIC_CLASSES or (struct.unpack_from("<I", flags)[0] >> 11) & 1:
        return name, None  # not a real numeric array
    typ, real, p = element(data, p)
    return name, {"dims": values(5, dims), "data": values(typ, real)}


def read(path):
    buf = open(path, "rb").read()
    assert buf[:6] == b"MATLAB", path
    out, pos = {}, 128
    while pos + 8 <= len(buf):
        typ, data, pos = element(buf, pos)
        if typ == 15:
            data = zlib.decompress(data)
            typ, data, _ = element(data, 0)
        if typ == 14:
            name, m = matrix(data)
            if m is not None:
                out[name] = m
    return out


if __name__ == "__main__":
    got = read(sys.argv[1])
    print(json.dumps({n: got[n] for n in sys.argv[2:]}))

"""A minimal binary little-endian PLY reader for the tests, independent of kfuse's writer:
it follows the header's element and property declarations (no fixed layout assumed)."""

from pathlib import Path

import numpy as np

_SCALARS = {
    "char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1",
    "short": "<i2", "ushort": "<u2", "int16": "<i2", "uint16": "<u2",
    "int": "<i4", "uint": "<u4", "int32": "<i4", "uint32": "<u4",
    "float": "<f4", "double": "<f8", "float32": "<f4", "float64": "<f8",
}


def read_ply(path: Path) -> dict:
    """{element name: structured array}; a list property must have a fixed count per row
    (triangles), returned as one (N, count) field."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0", lines[:2]
    elements = []  # (name, count, [(prop, dtype or (count dtype, item dtype))])
    for line in lines[2:]:
        words = line.split()
        if words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and words[1] == "list":
            elements[-1][2].append((words[4], (_SCALARS[words[2]], _SCALARS[words[3]])))
        elif words[0] == "property":
            elements[-1][2].append((words[2], _SCALARS[words[1]]))
    out, offset = {}, end
    for name, count, props in elements:
        fields = []
        for prop, dt in props:
            if isinstance(dt, tuple):
                # Peek the first row's list length; every row must have the same.
                n = int(np.frombuffer(data, dt[0], 1, offset + sum(np.dtype(f[1]).itemsize
                                                                   for f in fields))[0])
                fields.append((prop + "_count", dt[0]))
                fields.append((prop, dt[1], (n,)))
            else:
                fields.append((prop, dt))
        dtype = np.dtype(fields)
        arr = np.frombuffer(data, dtype, count, offset)
        for f in fields:
            if f[0].endswith("_count"):
                assert (arr[f[0]] == arr[f[0]][0]).all(), f"{path}: {name} lists differ in length"
        out[name] = arr
        offset += dtype.itemsize * count
    assert offset == len(data), f"{path}: {len(data) - offset} bytes after the last element"
    return out

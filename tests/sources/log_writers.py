"""Small writers of flight logs with known content, for the reader tests.

ULog (PX4's file format: a 16-byte header, then ``F`` format, ``A`` subscription and ``D``
data messages, each ``uint16 size, uint8 type`` then the payload, little endian and packed)
and DataFlash (ArduPilot's: text lines ``NAME, v1, v2, ...`` after ``FMT`` lines; binary
messages ``0xA3 0x95 id`` then the payload packed by the ``FMT`` format characters).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

#: ULog field types and their struct codes.
_ULOG_TYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "float": "f", "double": "d",
               "uint8_t": "B"}


def _ulog_code(typ: str) -> str:
    """``float`` -> ``f``, ``float[4]`` -> ``4f``."""
    base, _, count = typ.partition("[")
    return count.rstrip("]") + _ULOG_TYPES[base]


def _ulog_message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, topics: list[tuple[str, int, list[tuple[str, str]], list[tuple]]]
               ) -> Path:
    """A ULog file: ``topics`` are ``(name, multi_id, [(type, field), ...], rows)``; the
    first field must be ``uint64_t timestamp`` (microseconds). Rows are written in time order
    across topics, as a logger does."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    for name in dict.fromkeys(t[0] for t in topics):
        fields = next(t[2] for t in topics if t[0] == name)
        text = f"{name}:" + "".join(f"{typ} {field};" for typ, field in fields)
        out += _ulog_message(b"F", text.encode())
    for msg_id, (name, multi_id, _, _) in enumerate(topics):
        out += _ulog_message(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
    records = []
    for msg_id, (_, _, fields, rows) in enumerate(topics):
        code = "<H" + "".join(_ulog_code(typ) for typ, _ in fields)
        records += [(row[0], msg_id, struct.pack(code, msg_id, *_flat(row))) for row in rows]
    for _, _, payload in sorted(records, key=lambda r: (r[0], r[1])):
        out += _ulog_message(b"D", payload)
    path.write_bytes(bytes(out))
    return path


def _flat(row: tuple) -> list:
    """A row's values with array fields spread out (integers kept as integers)."""
    out: list = []
    for v in row:
        out.extend(v if isinstance(v, list | tuple) else [v])
    return out


#: DataFlash format characters used here and their struct codes.
_DF_CODES = {"Q": "Q", "B": "B", "f": "f", "I": "I", "h": "h", "n": "4s", "N": "16s",
             "Z": "64s", "b": "b", "H": "H", "i": "i", "d": "d", "q": "q", "M": "b", "c": "h",
             "C": "H", "e": "i", "E": "I", "L": "i", "a": "64s", "g": "e"}
_FMT = (128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")


def write_dataflash(path: Path, messages: dict[str, tuple[str, str, list[tuple]]],
                    binary: bool) -> Path:
    """A DataFlash log: ``messages`` maps a name to ``(format, columns, rows)``, the first
    column ``TimeUS``. Text (``.log``) or binary (``.bin``); rows interleaved in time order."""
    ids = {name: 129 + i for i, name in enumerate(messages)}
    records = [(row[0], name, row) for name, (_, _, rows) in messages.items() for row in rows]
    records.sort(key=lambda r: (r[0], ids[r[1]]))
    if not binary:
        lines = [f"FMT, {_FMT[0]}, 89, {_FMT[1]}, {_FMT[2]}, {_FMT[3]}"]
        for name, (fmt, cols, _) in messages.items():
            size = 3 + struct.calcsize("<" + "".join(_DF_CODES[c] for c in fmt))
            lines.append(f"FMT, {ids[name]}, {size}, {name}, {fmt}, {cols}")
        lines += [f"{name}, " + ", ".join(_text(v) for v in row) for _, name, row in records]
        path.write_text("\n".join(lines) + "\n")
        return path
    out = bytearray()

    def fmt_message(type_id: int, name: str, fmt: str, cols: str) -> bytes:
        size = 3 + struct.calcsize("<" + "".join(_DF_CODES.get(c, "") for c in fmt)) \
            if type_id != 128 else 89
        return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, size, name.encode(),
                                             fmt.encode(), cols.encode())

    out += fmt_message(*_FMT)
    for name, (fmt, cols, _) in messages.items():
        out += fmt_message(ids[name], name, fmt, cols)
    for _, name, row in records:
        fmt = messages[name][0]
        out += b"\xa3\x95" + bytes([ids[name]]) + struct.pack(
            "<" + "".join(_DF_CODES[c] for c in fmt), *row)
    path.write_bytes(bytes(out))
    return path


def _text(value: object) -> str:
    return repr(float(value)) if isinstance(value, float | np.floating) else str(value)

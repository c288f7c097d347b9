"""A small PX4 ULog writer for test fixtures (the file format of PX4's logger, version 1).

Header (``ULog`` 01 12 35, version, start timestamp), the flag-bits message, one format
message per topic, an ``sys_name`` info, then one ``A`` (add logged message) per topic and
``D`` (data) records in time order. Fields are packed little-endian without padding, as the
format strings declare them; pyulog reads exactly this.
"""
from __future__ import annotations

import struct
from pathlib import Path

__all__ = ["ULogWriter"]

_TYPES = {"uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
          "uint8_t": "B", "int8_t": "b", "float": "f", "double": "d", "bool": "?"}


class ULogWriter:
    """``topic(name, fields)`` declares a topic (fields: ``[(type, name)]``, ``type[N]`` for
    arrays; the first must be ``uint64_t timestamp``); ``add(name, values)`` queues one record;
    ``write(path)`` writes the file with the records sorted by timestamp."""

    def __init__(self) -> None:
        self.topics: dict[str, list[tuple[str, str]]] = {}
        self.records: list[tuple[int, str, tuple]] = []

    def topic(self, name: str, fields: list[tuple[str, str]]) -> None:
        if fields[0] != ("uint64_t", "timestamp"):
            raise ValueError("the first field of a ULog topic is uint64_t timestamp")
        self.topics[name] = fields

    def add(self, name: str, values: tuple) -> None:
        self.records.append((int(values[0]), name, tuple(values)))

    def _pack_format(self, name: str) -> str:
        out = "<"
        for ftype, _ in self.topics[name]:
            base, _, count = ftype.partition("[")
            out += (count.rstrip("]") if count else "") + _TYPES[base]
        return out

    def write(self, path: Path) -> Path:
        def msg(kind: str, payload: bytes) -> bytes:
            return struct.pack("<HB", len(payload), ord(kind)) + payload

        start = min((r[0] for r in self.records), default=0)
        out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start))
        out += msg("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
        for name, fields in self.topics.items():
            text = f"{name}:" + "".join(f"{t} {n};" for t, n in fields)
            out += msg("F", text.encode())
        key = b"char[4] sys_name"
        out += msg("I", bytes([len(key)]) + key + b"PX4\x00")
        ids = {}
        for k, name in enumerate(self.topics):
            ids[name] = k
            out += msg("A", struct.pack("<BH", 0, k) + name.encode())
        packers = {name: struct.Struct(self._pack_format(name)) for name in self.topics}
        for _, name, values in sorted(self.records, key=lambda r: r[0]):
            flat = []
            for v in values:
                flat.extend(v if isinstance(v, (tuple, list)) else [v])
            out += msg("D", struct.pack("<H", ids[name]) + packers[name].pack(*flat))
        path.write_bytes(bytes(out))
        return path

"""The link's ``.tlog`` record: flushed at least once a second of wall time, capped and rotated.

Each frame is written as MAVProxy's tlog does: an 8-byte big-endian UNIX time in microseconds,
then the raw frame. The file is written through a buffer (a frame per ``write`` call would cost
a system call per message) but flushed to the operating system whenever a second of wall time
has passed since the last flush, so a crash of the companion loses at most about one second
(issue 10: the 64 KB buffer alone lost ~23 s). With ``max_bytes`` > 0 the file is rotated
when it would grow past it: ``companion.tlog`` -> ``companion.tlog.1`` -> ... ->
``companion.tlog.<keep>`` (the oldest deleted), so the record never takes more than about
``(keep + 1) * max_bytes`` of disk.
"""
from __future__ import annotations

import os
import struct
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["FLUSH_WALL_S", "KEEP_ROTATED", "Tlog"]

FLUSH_WALL_S = 1.0
KEEP_ROTATED = 3
_STAMP = struct.Struct(">Q")


class Tlog:
    """Append-only tlog writer with a wall-time flush and size rotation."""

    def __init__(self, path: str | os.PathLike, max_bytes: int = 0, keep: int = KEEP_ROTATED,
                 wall: Callable[[], float] = time.monotonic, unix: Callable[[], float] = time.time) -> None:
        if max_bytes < 0 or keep < 1:
            raise ValueError(f"tlog cap {max_bytes} bytes / keep {keep}: cap >= 0 and keep >= 1")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.max_bytes = max_bytes
        self.keep = keep
        self.wall = wall
        self.unix = unix
        self.rotations = 0
        self.flushes = 0
        self._file = open(self.path, "wb", buffering=1 << 16)
        self._size = 0
        self._last_flush = wall()

    def write(self, frame: bytes) -> None:
        record = _STAMP.pack(int(self.unix() * 1e6) & ~3) + (frame if type(frame) is bytes else bytes(frame))
        if self.max_bytes and self._size + len(record) > self.max_bytes and self._size > 0:
            self._rotate()
        self._file.write(record)
        self._size += len(record)

    def write_all(self, frames: list) -> None:
        """Frames that arrived together (one datagram): one time stamp for all, as :meth:`write` each."""
        if not frames:
            return
        stamp = _STAMP.pack(int(self.unix() * 1e6) & ~3)
        if self.max_bytes and self._size + len(stamp) * len(frames) + sum(map(len, frames)) > self.max_bytes:
            for frame in frames:   # the cap falls inside these records: rotate where write would
                record = stamp + bytes(frame)
                if self._size + len(record) > self.max_bytes and self._size > 0:
                    self._rotate()
                self._file.write(record)
                self._size += len(record)
            return
        data = stamp + stamp.join(frames)   # stamp, frame, stamp, frame, ...
        self._file.write(data)
        self._size += len(data)

    def maybe_flush(self) -> None:
        """Flush if a second of wall time has passed since the last flush (call it often)."""
        now = self.wall()
        if now - self._last_flush >= FLUSH_WALL_S:
            self._file.flush()
            self._last_flush = now
            self.flushes += 1

    def _rotate(self) -> None:
        self._file.close()
        for index in range(self.keep, 0, -1):
            older = self.path.with_name(f"{self.path.name}.{index}")
            newer = self.path if index == 1 else self.path.with_name(f"{self.path.name}.{index - 1}")
            if newer.exists():
                os.replace(newer, older)
        self._file = open(self.path, "wb", buffering=1 << 16)
        self._size = 0
        self.rotations += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

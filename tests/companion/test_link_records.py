"""The link's records and the systemd hooks: tlog flushed each wall second and rotated at its cap;
sd_notify datagrams on a real Unix socket (issue 10, items 8-9)."""
from __future__ import annotations

import socket

from companion.io.link.tlog import Tlog
from companion.sdnotify import Notifier


class Wall:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_tlog_reaches_the_file_within_a_second_of_wall_time(tmp_path):
    wall = Wall()
    tlog = Tlog(tmp_path / "c.tlog", wall=wall)
    try:
        tlog.write(b"\xfd" + b"x" * 40)
        tlog.maybe_flush()
        assert (tmp_path / "c.tlog").stat().st_size == 0          # buffered: less than a second
        wall.t += 1.0
        tlog.maybe_flush()
        assert (tmp_path / "c.tlog").stat().st_size == 8 + 41     # stamp + frame, on disk for a reader
    finally:
        tlog.close()


def test_tlog_rotates_at_its_cap_and_keeps_three(tmp_path):
    tlog = Tlog(tmp_path / "c.tlog", max_bytes=1000, keep=3)
    frame = b"\xfd" + b"y" * 91                                    # 100 bytes with the stamp
    for _ in range(60):
        tlog.write(frame)
    tlog.close()
    sizes = {p.name: p.stat().st_size for p in tmp_path.iterdir()}
    assert set(sizes) == {"c.tlog", "c.tlog.1", "c.tlog.2", "c.tlog.3"}
    assert all(size <= 1000 for size in sizes.values()) and tlog.rotations == 5
    assert sum(sizes.values()) == 4000                             # the newest 40 frames kept


def test_sd_notify_ready_and_watchdog_at_half_the_period(tmp_path):
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    wall = Wall()
    try:
        notifier = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"}, wall=wall)
        assert notifier.ready()
        assert sock.recv(100) == b"READY=1"
        assert notifier.watchdog() and sock.recv(100) == b"WATCHDOG=1"
        wall.t += 0.9
        assert not notifier.watchdog()                             # within half of WatchdogSec=2 s
        wall.t += 0.1
        assert notifier.watchdog() and sock.recv(100) == b"WATCHDOG=1"
    finally:
        sock.close()
    outside = Notifier({})
    assert not outside.ready() and not outside.watchdog()


def test_a_datagrams_frames_are_recorded_as_written_one_by_one(tmp_path):
    """``write_all`` (a datagram's frames, one time stamp) writes the records ``write`` writes for each,
    and rotates at the cap the same way (datagrams under the cap written whole, one crossing it
    record by record), every rotated file included."""
    frames = [b"\xfd" + bytes([k]) * (20 + k) for k in range(12)]
    for cap in (0, 120, 200, 260, 350):
        (tmp_path / str(cap)).mkdir()
        by_one = Tlog(tmp_path / str(cap) / "one.tlog", max_bytes=cap, keep=9, unix=lambda: 1.5e9)
        for frame in frames:
            by_one.write(frame)
        by_one.close()
        together = Tlog(tmp_path / str(cap) / "all.tlog", max_bytes=cap, keep=9, unix=lambda: 1.5e9)
        for start, end in ((0, 2), (2, 5), (5, 6), (6, 12)):
            together.write_all([bytearray(f) if start % 2 else f for f in frames[start:end]])
        together.close()
        for suffix in [""] + [f".{k}" for k in range(1, 10)]:
            one, both = tmp_path / str(cap) / f"one.tlog{suffix}", tmp_path / str(cap) / f"all.tlog{suffix}"
            assert one.exists() == both.exists() and (not one.exists() or one.read_bytes() == both.read_bytes())
        assert together.rotations == by_one.rotations and (by_one.rotations > 0) == (cap > 0)

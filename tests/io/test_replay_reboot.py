"""LogReplaySource across a reboot inside a tlog: UNIX-stamped GPS_RAW_INT must not stay on the
old boot's clock until the new boot's SYSTEM_TIME arrives (real frames written with pymavlink)."""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion.io.sensors.base import AttitudeSample, GpsSample, StreamEnd  # noqa: E402
from companion.io.sensors.replay import LogReplaySource  # noqa: E402

UNIX0 = 1_527_811_200.0


def _tlog(path: Path) -> Path:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()

    def put(msg, unix: float) -> None:
        out.extend(int(unix * 1e6).to_bytes(8, "big") + msg.pack(mav))

    for boot, (unix_boot0, seconds) in enumerate(((UNIX0, 60), (UNIX0 + 70.0, 20))):
        for k in range(seconds * 5):
            t = 1.0 + 0.2 * k
            unix = unix_boot0 + t
            put(mavlink.MAVLink_attitude_message(int(t * 1e3), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), unix)
            put(mavlink.MAVLink_gps_raw_int_message(int(unix * 1e6), 3, -353000000, 1491000000, 600000, 80, 120,
                                                    0, 0, 12), unix)
            # boot 1 sends SYSTEM_TIME from the start; boot 2 only after 10 s (GPS time first)
            if k % 5 == 0 and (boot == 0 or t > 10.0):
                put(mavlink.MAVLink_system_time_message(int(unix * 1e6), int(t * 1e3)), unix)
    path.write_bytes(bytes(out))
    return path


def test_gps_after_a_reboot_is_on_the_new_boot_clock(tmp_path: Path) -> None:
    src = LogReplaySource(_tlog(tmp_path / "reboot.tlog"), speed=None, max_batch=100_000)
    samples = []
    with src:
        while not src.finished:
            samples += [s for s in src.poll() if not isinstance(s, StreamEnd)]
    reboot = next(k for k in range(1, len(samples)) if samples[k].time_s < samples[k - 1].time_s - 1.0)
    after = samples[reboot:]
    att = [s.time_s for s in after if isinstance(s, AttitudeSample)]
    gps = [s.time_s for s in after if isinstance(s, GpsSample)]
    assert len(gps) == len(att) == 100
    assert max(abs(g - a) for g, a in zip(gps, att)) < 0.05   # not ~70 s late on the old boot's clock

"""Which reader a log needs, from its first bytes (or a ``.csv`` name), and its boots.

ULog (``ULog`` 01 12 35) -> :mod:`fcmpc.replay.ulog`; ``.csv`` -> :mod:`fcmpc.replay.csvlog`; a DataFlash
``.bin`` or MAVLink ``.tlog`` -> :mod:`fcmpc.replay.mavlog`; anything else is a SensorError saying
what the file is not.
"""
from __future__ import annotations

import os
from pathlib import Path

from companion.io.sensors.base import SensorError
from companion.io.sensors.replay import log_head, sniff_log_format
from fcmpc.replay.csvlog import read_csv
from fcmpc.replay.logdata import CSV, ULOG, LogData
from fcmpc.replay.mavlog import read_mavlink_boots
from fcmpc.replay.ulog import read_ulog

__all__ = ["sniff_format", "read_boots"]

ULOG_MAGIC = b"ULog\x01\x12\x35"


def sniff_format(path: str | os.PathLike[str]) -> str:
    """``dataflash``, ``tlog``, ``ulog`` or ``csv``; SensorError naming what the file is not."""
    p = Path(path)
    head = log_head(p)
    if head.startswith(ULOG_MAGIC):
        return ULOG
    if p.suffix.lower() == ".csv":
        return CSV
    try:
        return sniff_log_format(p, head)
    except SensorError as err:
        raise SensorError(f"{err}; nor a PX4 ULog (starts 'ULog' 01 12 35) nor a .csv "
                          "(see the README's CSV columns)") from err


def read_boots(path: str | os.PathLike[str], mag_instance: int = 0) -> list[LogData]:
    """Every boot of a log, oldest first (a ULog or a CSV is one boot); SensorError on bad input."""
    fmt = sniff_format(path)
    if fmt == ULOG:
        return [read_ulog(path, mag_instance)]
    if fmt == CSV:
        return [read_csv(path)]
    return read_mavlink_boots(path, fmt, mag_instance)

"""What the companion hands the status page: a frozen record of its state at one moment.

The page never reads the companion's objects (they change under it on another thread): the
companion builds a :class:`StatusSnapshot` from its parts (:mod:`companion.process.status`)
and hands over the new one; replacing a reference is atomic, so the page's thread reads a
whole snapshot or the one before, never a mix. Units per :mod:`companion`; positions in
degrees, distances in metres, times in message seconds unless the name says ``wall``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

__all__ = ["SensorHealth", "StatusSnapshot", "json_ready"]


@dataclass(frozen=True)
class SensorHealth:
    """One input the companion depends on: its age (message time) against its timeout."""

    name: str               # mag, attitude, heartbeat, gps
    age_s: float            # since its last valid sample (inf: never)
    limit_s: float          # the failsafe's timeout (nan: none, e.g. GPS, which is never needed)
    ok: bool
    detail: str = ""        # what the decoder last found wrong, or a fix type


@dataclass(frozen=True)
class StatusSnapshot:
    """The companion at ``msg_time_s``; NaN where there is nothing yet (no mission, no estimate)."""

    wall_time_s: float                  # UNIX time the snapshot was taken
    msg_time_s: float                   # the flight controller's boot time
    state: str                          # the process's phase: wait_fc, startup, ready, running, done
    phase: str                          # the mission's: probe1, probe2, cruise, hold, arrived, failed ("" before)
    mission: int                        # missions started (restarts count up)
    step: int                           # the mission's step
    restarts: int
    est_lat_deg: float
    est_lon_deg: float
    est_sigma_m: float                  # 1-sigma per axis
    est_cov_en_m2: tuple[float, float, float]   # east-east, east-north, north-north (NaN: the filter gave none)
    fix_lat_deg: float                  # the step's geomagnetic fix
    fix_lon_deg: float
    start_lat_deg: float
    start_lon_deg: float
    dest_lat_deg: float
    dest_lon_deg: float
    remaining_m: float
    course_deg: float                   # commanded, from north clockwise
    speed_mps: float
    failsafe: bool
    reasons: tuple[str, ...]            # the failsafe's reasons now (empty: healthy)
    sensors: tuple[SensorHealth, ...]
    fc_autopilot: str
    fc_sysid: int
    fc_mode: str
    fc_armed: bool
    link: tuple[tuple[str, int], ...]   # the link's counters, name and value
    statustexts: tuple[str, ...]        # the last things the companion said, oldest first, "[msg time] text"
    fc_statustexts: tuple[str, ...] = ()   # the flight controller's last STATUSTEXTs, the same way

    def as_json(self) -> dict:
        """A dict for ``json.dumps``: non-finite numbers as ``null`` (JSON has no NaN)."""
        return json_ready(asdict(self))


def json_ready(value):
    """``value`` with every non-finite float replaced by None and tuples by lists.

    >>> json_ready({"a": (1.0, float("nan")), "b": [float("inf"), "x"]})
    {'a': [1.0, None], 'b': [None, 'x']}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    return value

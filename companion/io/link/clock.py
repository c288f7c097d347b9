"""Message time from the pinned flight controller's stamps, judged so one frame can never move it far.

The companion's clock is the flight controller's boot time (``time_boot_ms``, boot-based
``time_usec``, SYSTEM_TIME). Only the pinned flight controller's messages reach
:class:`MessageClock` (:mod:`companion.io.link.peers` pins it), and each stamp is judged:

=====================================  =====================================================
stamp ``t`` against the clock ``now``  verdict
=====================================  =====================================================
``now - reorder_s <= t <= now``        on time (a reordered datagram): kept, clock not moved
``now < t <= now + future_s``          on time: kept, the clock moves to ``t``
``now - reboot_s <= t < now - reorder_s``  out of order: counted (:attr:`out_of_order`), dropped
``t < now - reboot_s``                 a *new time base* candidate (a reboot?): dropped until
``t > now + future_s``                 confirmed; counted (:attr:`far_past`, :attr:`far_future`)
=====================================  =====================================================

A candidate base is adopted only on consistent evidence: at least ``evidence`` stamps that
follow each other as a clock does (each within ``[last - reorder_s, last + future_s]`` of the
previous one), one of them a SYSTEM_TIME (or ``4 * evidence`` stamps when none is streamed),
and a HEARTBEAT from the flight controller while the candidate grew, with no stamp on the old
base in between (the old base still ticking means the candidate is forged or stale). Adopting a
base that went back is a reboot (:attr:`reboots`, which the application watches); one that went
forward is a time jump (:attr:`jumps`: a long link outage). A fuzzer's random stamps never line
up, a single forged frame is one stamp, and a genuine reboot is confirmed within about one
SYSTEM_TIME period.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MessageClock"]


@dataclass
class _Candidate:
    """A time base seen in stamps that do not fit the clock, growing until confirmed or replaced."""

    last_s: float
    stamps: int = 1
    system_time: bool = False
    heartbeats: int = 0
    unix_minus_boot_s: float | None = None


class MessageClock:
    """Message time (s since the flight controller booted), judged stamp by stamp (module docstring).

    ``time_usec`` values that are UNIX time (> 1e15 us, e.g. GPS_RAW_INT) are converted with
    SYSTEM_TIME's pairing of UNIX and boot time.

    >>> c = MessageClock()
    >>> c.observe_boot_ms(5000), c.observe_boot_ms(10_000_000), c.far_future   # one far-future frame
    (5.0, 5.0, 1)
    """

    UNIX_USEC_LIMIT = 1_000_000_000_000_000   # ~31.7 years after boot; larger means UNIX time

    def __init__(self, reboot_s: float = 10.0, future_s: float = 10.0, reorder_s: float = 1.0,
                 evidence: int = 5) -> None:
        self.now_s = math.nan
        self.unix_minus_boot_s: float | None = None
        self.reboot_s = reboot_s
        self.future_s = future_s
        self.reorder_s = reorder_s
        self.evidence = evidence
        self.reboots = 0
        self.jumps = 0
        self.out_of_order = 0
        self.far_future = 0
        self.far_past = 0
        self._candidate: _Candidate | None = None

    @property
    def started(self) -> bool:
        return math.isfinite(self.now_s)

    @property
    def dropped(self) -> int:
        """Stamps refused so far (out of order, or on a time base not (yet) confirmed)."""
        return self.out_of_order + self.far_future + self.far_past

    # --- judging --------------------------------------------------------------------------
    def judge(self, t: float, system_time: bool = False, unix_minus_boot_s: float | None = None) -> bool:
        """True if a message stamped ``t`` (s of boot time) is on the clock's time base and kept."""
        if not math.isfinite(t):
            self.far_future += 1
            return False
        now = self.now_s
        if now != now:   # not started (NaN)
            self.now_s = t
            return True
        if now - self.reorder_s <= t <= now + self.future_s:
            if t > now:
                self.now_s = t
            self._candidate = None          # the old base still ticks: any candidate was forged or stale
            return True
        if now - self.reboot_s <= t < now:
            self.out_of_order += 1
            return False
        if t > now:
            self.far_future += 1
        else:
            self.far_past += 1
        return self._grow(t, system_time, unix_minus_boot_s)

    def heartbeat(self) -> None:
        """The pinned flight controller's HEARTBEAT arrived (evidence for a candidate base)."""
        if self._candidate is not None:
            self._candidate.heartbeats += 1

    def _grow(self, t: float, system_time: bool, unix_minus_boot_s: float | None) -> bool:
        cand = self._candidate
        if cand is None or not cand.last_s - self.reorder_s <= t <= cand.last_s + self.future_s:
            self._candidate = _Candidate(t, system_time=system_time, unix_minus_boot_s=unix_minus_boot_s)
            return False
        cand.last_s = max(cand.last_s, t)
        cand.stamps += 1
        if system_time:
            cand.system_time = True
            cand.unix_minus_boot_s = unix_minus_boot_s
        enough = cand.stamps >= self.evidence and (cand.system_time or cand.stamps >= 4 * self.evidence)
        if not (enough and cand.heartbeats > 0):
            return False
        if cand.last_s < self.now_s:
            self.reboots += 1
        else:
            self.jumps += 1
        self.now_s = cand.last_s
        self.unix_minus_boot_s = cand.unix_minus_boot_s
        self._candidate = None
        return True

    # --- the stamps of the messages ------------------------------------------------------------
    def observe_boot_ms(self, time_boot_ms: int) -> float:
        """Judge a ``time_boot_ms`` stamp; the clock after it."""
        self.judge(time_boot_ms * 1e-3)
        return self.now_s

    def observe_system_time(self, time_unix_usec: int, time_boot_ms: int) -> bool:
        """Judge SYSTEM_TIME; on the clock's base its UNIX-boot pairing is kept. True if kept."""
        t = time_boot_ms * 1e-3
        offset = time_unix_usec * 1e-6 - t if time_unix_usec else None
        kept = self.judge(t, system_time=True, unix_minus_boot_s=offset)
        if kept and offset is not None:
            self.unix_minus_boot_s = offset
        return kept

    def stamp_usec(self, time_usec: int) -> float | None:
        """Boot time in s of a ``time_usec`` field (boot or UNIX), None if it cannot be placed."""
        if 0 < time_usec < self.UNIX_USEC_LIMIT:
            return time_usec * 1e-6
        if time_usec and self.unix_minus_boot_s is not None:
            return time_usec * 1e-6 - self.unix_minus_boot_s
        return None

"""Fault injection of the stand-in: the scenario's ``[[faults]]`` schedule switched on and off in time.

Each fault (``kind``, ``at_s``, ``duration_s``, ``value``; see :data:`sitl.scenario.FAULT_KINDS`)
is active on ``[at_s, at_s + duration_s)`` of simulated time and announced by STATUSTEXT when
it starts and ends. :class:`FaultInjector` turns the active set into flags the other parts
read: the magnetometer (``mag_off``, ``mag_stuck``, ``mag_nan``, ``mag_spike_nt``), GPS
(``gps_off``; the SIM_GPS1_ENABLE parameter sets it too), the heartbeat (``heartbeat_off``),
the link (``loss`` and ``dup`` probabilities, ``delay_us``) and the storm (``storm_scale``:
None without a ``storm_onset`` fault, else the scale of the storm part of the field, 0 before
the onset). ``fc_reboot`` is an event: when one starts :attr:`FaultInjector.reboot_due` is set
for the server (:meth:`sitl.fc.server.SitlServer` restarts the boot clock, disarms and
initialises for the fault's duration; the vehicle's true position and the parameters are kept).
"""
from __future__ import annotations

import math

from sitl.clock import US_PER_S, SimClock
from sitl.guidance import SEVERITY_NOTICE, SEVERITY_WARNING
from sitl.scenario import Fault

__all__ = ["FaultInjector"]

NEVER_US = 1 << 62


class FaultInjector:
    """The fault schedule and the flags of the faults active now."""

    def __init__(self, faults: tuple[Fault, ...], clock: SimClock, counters, say) -> None:
        self.faults = tuple(faults)
        self.clock = clock
        self.counters = counters
        self.say = say                  # say(key, severity, text): STATUSTEXT
        self._times = sorted({f.at_s for f in self.faults} | {f.at_s + f.duration_s for f in self.faults
                                                              if math.isfinite(f.duration_s)})
        self.active: tuple[Fault, ...] = ()
        self.loss = self.dup = 0.0
        self.delay_us = 0
        self.heartbeat_off = self.gps_off = self.mag_off = self.mag_stuck = self.mag_nan = False
        self._gps_fault = False
        self.gps_disabled = False       # SIM_GPS1_ENABLE = 0: denied like a gps_off fault
        self.mag_spike_nt = 0.0
        self.reboot_due: Fault | None = None   # an fc_reboot fault that just started (the server takes it)
        self.storm_scale: float | None = None if not any(f.kind == "storm_onset" for f in self.faults) else 0.0
        self.next_us = self._next_change_us(-1)

    def _next_change_us(self, after_us: int) -> int:
        for t in self._times:
            us = int(round(t * US_PER_S))
            if us > after_us:
                return us
        return NEVER_US

    def update(self) -> bool:
        """Re-evaluate the active faults at the clock's time; True when the storm scale was re-set."""
        now = self.clock.time_s + 1e-9
        active = tuple(f for f in self.faults if f.active(now))
        storm_changed = False
        if active != self.active:
            old = {(f.kind, f.at_s) for f in self.active}
            new = {(f.kind, f.at_s) for f in active}
            for f in active:
                if (f.kind, f.at_s) not in old:
                    self.counters.add(f"fault_{f.kind}")
                    if f.kind == "fc_reboot":
                        self.reboot_due = f
                    self.say(None, SEVERITY_WARNING, f"SITL fault {f.kind} ON" + (f" {f.value:g}" if f.value else ""))
            for f in self.active:
                if (f.kind, f.at_s) not in new:
                    self.say(None, SEVERITY_NOTICE, f"SITL fault {f.kind} OFF")
            self.active = active
            kinds = [f.kind for f in active]
            self.mag_off = "mag_off" in kinds
            self.mag_stuck = "mag_stuck" in kinds
            self.mag_nan = "mag_nan" in kinds
            self.mag_spike_nt = sum(f.value for f in active if f.kind == "mag_spike")
            self._gps_fault = "gps_off" in kinds
            self.gps_off = self._gps_fault or self.gps_disabled
            self.heartbeat_off = "heartbeat_off" in kinds
            self.loss = min(1.0, max(0.0, max([f.value for f in active if f.kind == "link_loss"], default=0.0)))
            self.dup = min(1.0, max(0.0, max([f.value for f in active if f.kind == "link_duplicate"], default=0.0)))
            self.delay_us = int(max([f.value for f in active if f.kind == "link_delay"], default=0.0) * US_PER_S)
            if self.storm_scale is not None:
                onset = [f.value or 1.0 for f in active if f.kind == "storm_onset"]
                self.storm_scale = max(onset) if onset else 0.0
                storm_changed = True
        self.next_us = self._next_change_us(self.clock.t_us)
        return storm_changed

    def set_gps_enabled(self, enabled: bool) -> None:
        """The SIM_GPS1_ENABLE switch: when off, GPS is denied exactly as by a ``gps_off`` fault."""
        self.gps_disabled = not enabled
        self.gps_off = self._gps_fault or self.gps_disabled

    def describe(self) -> str:
        """The active faults for the truth log: ``kind`` or ``kind=value``, ``;``-separated."""
        return ";".join(f.kind if not f.value else f"{f.kind}={f.value:g}" for f in self.active)

"""What the companion says when its navigation filter changes how it treats the field.

After every control step the filter's disturbance monitor
(:class:`companion.nav.disturbance.DisturbanceMonitor`) says whether a space-weather reading
declares a storm, whether a disturbance is active (declared, or found by the innovations), and
with a weighted element set whether F is weighed (:meth:`companion.nav.elements.ElementSet.measured_rows`).
Each change is one STATUSTEXT, as a flight controller announces a change of its estimator's
state: an operator sees a storm the navigator took on mid-flight, or F set aside when the feed
lapsed, instead of finding it in the log afterwards. The first step is described by the start-up
words (:meth:`FilterWords.start_words`), so only later changes are said.

Pure: the monitor's state and the readings in, (text, severity) pairs out; the caller sends them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.io.link import mavlink
from companion.nav.disturbance import storm_declared
from companion.nav.elements import ElementSet

__all__ = ["FilterState", "FilterWords", "declared_by"]

Said = tuple[str, int]    # (STATUSTEXT text, MAV_SEVERITY)


@dataclass(frozen=True)
class FilterState:
    """What the words follow: a storm declared, a disturbance active, F weighed (None: no F)."""

    declared: bool
    active: bool
    f_weighed: bool | None

    @classmethod
    def of(cls, mission, at_start: bool = False) -> FilterState | None:
        """The state of ``mission``'s error-state filter after its last step; None without one
        (Table 3's path, or a test's stand-in core). ``at_start``: F as the start-up words
        describe it (the start's calibration measures F whatever the day; set 5 then weighs it
        only once a reading says quiet)."""
        flt = getattr(getattr(mission, "estimator", None), "filter", None)
        measured = getattr(mission, "measured", None)
        if flt is None or measured is None:
            return None
        monitor = flt.monitor
        quiet = monitor.index_quiet and not at_start
        weighed = (len(measured.measured_rows(monitor.declared, quiet)) == len(measured.names)
                   if measured.weighted else None)
        return cls(monitor.declared, monitor.active, weighed)


def declared_by(kp: float, symh_nt: float, config) -> str:
    """Which reading declares the storm, in words (``config``: a NavConfig's thresholds)."""
    if storm_declared(kp, config.kp_on):
        return f"NAV_KP {kp:g} >= FUS_KP_ON {config.kp_on:g}"
    return f"NAV_SYMH {symh_nt:g} <= FUS_SYMH_ON {config.symh_on_nt:g} nT"


def _storm_declared_words(mission, kp: float, symh_nt: float) -> Said:
    """The STATUSTEXT of a storm declared: which reading, and how the bias states now walk."""
    return (f"FcMPC: storm declared: {declared_by(kp, symh_nt, mission.config)}, {mission.estimator.storm_walk}"[:200],
            mavlink.MAV_SEVERITY_WARNING)


class FilterWords:
    """The last state said; :meth:`step` returns the words for what changed since."""

    def __init__(self) -> None:
        self.last: FilterState | None = None

    def start_words(self, mission, kp: float, symh_nt: float) -> list[Said]:
        """At a mission's first step: remember the state, and say a storm declared at the start."""
        self.last = state = FilterState.of(mission, at_start=True)
        return [_storm_declared_words(mission, kp, symh_nt)] if state is not None and state.declared else []

    def step(self, mission, kp: float, symh_nt: float) -> list[Said]:
        """After a later step: the words for each change of the state (none when nothing changed)."""
        state, last = FilterState.of(mission), self.last
        if state is None or state == last:
            return []
        self.last = state
        if last is None:   # resumed mid-mission: say where the filter stands
            last = FilterState(False, False, state.f_weighed)
        said: list[Said] = []
        if state.declared and not last.declared:
            said.append(_storm_declared_words(mission, kp, symh_nt))
        elif last.declared and not state.declared:
            readings = ", ".join(f"{name} {value:g}" for name, value in (("NAV_KP", kp), ("NAV_SYMH", symh_nt))
                                 if math.isfinite(value)) or "no fresh reading"
            said.append((f"FcMPC: storm no longer declared ({readings}): the innovations release the bias walk",
                         mavlink.MAV_SEVERITY_NOTICE))
        if state.active != last.active and not (state.declared or last.declared):
            said.append(("FcMPC: disturbance found by the innovations: the biases walk faster"
                         if state.active else "FcMPC: disturbance over: the biases walk at the quiet rate",
                         mavlink.MAV_SEVERITY_WARNING if state.active else mavlink.MAV_SEVERITY_NOTICE))
        if state.f_weighed is not None and state.f_weighed != last.f_weighed:
            if state.f_weighed:
                why = ("a fresh space-weather reading says quiet"
                       if mission.measured.code == ElementSet.WEIGHTED_WHEN_QUIET else "no storm declared")
                said.append((f"FcMPC: F weighed: {why}", mavlink.MAV_SEVERITY_NOTICE))
            else:
                why = "a storm is declared" if state.declared else "no fresh NAV_KP or NAV_SYMH says quiet"
                said.append((f"FcMPC: F set aside: {why}", mavlink.MAV_SEVERITY_NOTICE))
        return said

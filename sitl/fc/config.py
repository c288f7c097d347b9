"""What the flight-controller stand-in is started with: :class:`ServerConfig` and the fault syntax.

The CLI (:mod:`sitl.fc.cli`) fills a :class:`ServerConfig`; tests build one directly.
``validate()`` names the first setting out of range, so bad input never starts a run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.fc.lockstep import HANG_S
from sitl.guidance import DIALECTS
from sitl.scenario import FAULT_KINDS, Fault

__all__ = ["DEFAULT_OUT", "DEFAULT_SPEEDUP", "ServerConfig", "parse_fault"]

DEFAULT_OUT = "udp:127.0.0.1:14550"
DEFAULT_SPEEDUP = 1.0


def parse_fault(text: str) -> Fault:
    """``kind:at_s[:duration_s[:value]]`` -> Fault (duration ``inf`` or omitted = to the end).

    >>> parse_fault("link_loss:10:inf:0.25")
    Fault(kind='link_loss', at_s=10.0, duration_s=inf, value=0.25)
    """
    parts = text.split(":")
    if not 2 <= len(parts) <= 4 or parts[0] not in FAULT_KINDS:
        raise ValueError(f"fault {text!r}: expected kind:at_s[:duration_s[:value]], "
                         f"kind one of {', '.join(FAULT_KINDS)}")
    try:
        at = float(parts[1])
        duration = float(parts[2]) if len(parts) > 2 and parts[2] else math.inf
        value = float(parts[3]) if len(parts) > 3 and parts[3] else 0.0
    except ValueError:
        raise ValueError(f"fault {text!r}: at_s, duration_s and value must be numbers") from None
    if not (math.isfinite(at) and at >= 0.0 and duration > 0.0 and math.isfinite(value)):
        raise ValueError(f"fault {text!r}: need at_s >= 0, duration_s > 0, finite value")
    return Fault(parts[0], at, duration, value)


@dataclass
class ServerConfig:
    """Everything the simulator is started with (the CLI fills it; tests build it directly)."""

    scenario: str = "pacific"
    outs: tuple[str, ...] = ()          # udp:HOST:PORT senders (default DEFAULT_OUT when no endpoint given)
    masters: tuple[str, ...] = ()       # tcp:HOST:PORT / udpin:HOST:PORT listeners
    speedup: float | None = None        # sim s per wall s; None: 1 (or unlimited with lockstep); 0: unlimited
    lockstep: bool = False
    lockstep_period_s: float = 0.2
    lockstep_timeout_s: float = 2.0
    lockstep_start_timeout_s: float = 60.0
    lockstep_peer: tuple[int, int] | None = None
    lockstep_peer_pid: int | None = None  # wait while this process lives (no wall timeout), then go on
    lockstep_successor: bool = False     # then wait on a restarted companion holding its port
    lockstep_hang_s: float = HANG_S      # wall s a live companion may leave a boundary unanswered: a hang
    lockstep_slack: int = 1              # periods the companion may lag (0: the two processes alternate)
    duration_s: float | None = None     # stop after this much simulated time
    max_sim_s: float = 30 * 3600.0
    seed: int = 0
    autopilot: str = "ardupilot"
    sysid: int = 1
    setpoint_timeout_s: float | None = None
    cruise_speed_mps: float | None = None
    init_s: float = 1.0
    cruise: tuple[float, float] | None = None   # (course_deg, speed_mps): armed in guided from init_s
    log_dir: str | None = None
    truth_log: bool = True
    log_rate_hz: float = 1.0
    tlog: str | None = None             # path, "" = <log_dir>/sitl.tlog, None = no tlog
    faults: tuple[str, ...] = ()
    rates: tuple[str, ...] = ()         # NAME:HZ overrides of DEFAULT_RATES_HZ
    field_step_s: float = 1.0
    ins_step_s: float = 5.0
    wave_roll_deg: float = 3.0
    wave_pitch_deg: float = 2.0
    data_dir: str | None = None
    expected_duration_s: float | None = None
    space_weather_feed: tuple[str, ...] = ()   # the readings the world's ground station keeps up to date: NAV_KP, NAV_SYMH
    routing: bool = True
    batch: bool = True
    summary_json: str | None = None
    quiet: bool = False

    def validate(self) -> None:
        """Raise ValueError naming the first setting out of range."""
        checks = [
            ("speedup", self.speedup is None or self.speedup >= 0.0, ">= 0 (0 = unlimited)"),
            ("duration_s", self.duration_s is None or self.duration_s > 0.0, "> 0"),
            ("max_sim_s", self.max_sim_s > 0.0, "> 0"),
            ("lockstep_period_s", self.lockstep_period_s > 0.0, "> 0"),
            ("lockstep_timeout_s", self.lockstep_timeout_s > 0.0, "> 0"),
            ("lockstep_start_timeout_s", self.lockstep_start_timeout_s >= 0.0, ">= 0"),
            ("lockstep_peer_pid", self.lockstep_peer_pid is None or self.lockstep_peer_pid > 0, "> 0"),
            ("lockstep_hang_s", self.lockstep_hang_s > 0.0, "> 0"),
            ("init_s", self.init_s >= 0.0, ">= 0"),
            ("log_rate_hz", self.log_rate_hz >= 0.0, ">= 0"),
            ("field_step_s", self.field_step_s > 0.0, "> 0"),
            ("ins_step_s", self.ins_step_s > 0.0, "> 0"),
            ("setpoint_timeout_s", self.setpoint_timeout_s is None or self.setpoint_timeout_s > 0.0, "> 0"),
            ("sysid", 1 <= self.sysid <= 255, "in 1..255"),
            ("autopilot", self.autopilot in DIALECTS, f"one of {', '.join(DIALECTS)}"),
        ]
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"{name} = {getattr(self, name)!r} must be {rule}")

"""A companion process driven message by message (no simulator).

A pymavlink receiver plays the flight controller's socket, so what the companion sends is
read back from the wire. The ``rig`` fixture (conftest.py) gives an app armed in GUIDED, running.
"""
from __future__ import annotations

import os
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.app import AppOptions, CompanionApp, State
from companion.io.link import mavlink
from companion.io.sensors.base import SampleKind
from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.mission import Command
from companion.params import NavConfig, default_values
from tests.ports import free_port

ARMED_GUIDED = dict(type=11, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                    base_mode=mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                    custom_mode=15, system_status=4, mavlink_version=3)


def _msg(name: str, **fields):
    msg = getattr(mavlink, f"MAVLink_{name.lower()}_message")(**fields)
    msg.pack(mavlink.MAVLink(None, 1, 1))
    return msg


class FakeMission:
    """Stands in for the core: returns a prepared command."""

    def __init__(self, command: Command) -> None:
        self.config = NavConfig.from_values(default_values())
        self.measured = self.elements = ELEMENT_SETS[ElementSet.PAPER]   # what the navigator measures: D and I
        self.command = command
        self.k = command.step

    def step(self, meas):
        return self.command

    def reconfigure(self, new):
        return []

    def snapshot(self) -> dict:
        return dict(vars(self))


GOOD = Command(time_s=360.0, step=5, phase="cruise", course_rad=2.3, speed_mps=13.0, done=False, est_lat_deg=32.5,
               est_lon_deg=152.5, est_sigma_m=800.0, remaining_m=70_000.0, fix_lat_deg=32.5, fix_lon_deg=152.51)


def make_rig(tmp_path):
    port = free_port()
    fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    app = CompanionApp(AppOptions(connect=f"udpout:127.0.0.1:{port}", params=str(tmp_path / "p.parm"),
                                  log_dir=str(tmp_path / "log"), quiet=True, tlog=False))
    app.open()
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "base_mode": 1, "custom_mode": 4}))   # disarmed in HOLD
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=1000))
    assert app.state == State.STARTUP and not app.failsafe_active
    app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}   # sensors fresh
    app.handle(_msg("HEARTBEAT", **ARMED_GUIDED))
    app.machine.state = State.RUNNING
    app.mission_state.m0 = 0.0
    return app, fc


def _sent(fc, quiet_s: float = 0.15, limit_s: float = 3.0) -> list:
    """Everything received until the socket was quiet for ``quiet_s``."""
    out, deadline = [], time.monotonic() + limit_s
    while time.monotonic() < deadline:
        msg = fc.recv_match(blocking=True, timeout=quiet_s)
        if msg is None:
            break
        out.append(msg)
    return out


def _run_step(app: CompanionApp, command: Command) -> None:
    app.mission_state.mission = FakeMission(command)
    app.mag.averager.add(0.5, 1.0, 50.0)
    app.phases.step(app.now, 1.0)



"""The operator's hold / resume / start (COMMAND_LONG to component 191) and the status a ground
station reads back (companion.operator_status), on the rig: what the companion sends is read
from the wire."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.io.link import mavlink
from companion.operator_status import StatusReader, failsafe_names
from companion.process.machine import State
from tests.companion.process.rig import GOOD, _run_step, _sent
from tests.companion.process.test_phases import GUIDED, HOLD, _at, _mode_commands

GCS = (255, 190)   # MAVProxy's ids: an allowed ground station (LINK_GCS_ID*)


def _from(ids: tuple[int, int], name: str, **fields):
    msg = getattr(mavlink, f"MAVLink_{name.lower()}_message")(**fields)
    msg.pack(mavlink.MAVLink(None, *ids))
    return msg


def _command(app, command: int, param1: float = 0.0, ids: tuple[int, int] = GCS) -> None:
    app.handle(_from(ids, "COMMAND_LONG", target_system=1, target_component=191, command=command, confirmation=0,
                     param1=param1, param2=0, param3=0, param4=0, param5=0, param6=0, param7=0))


def _acks(sent: list) -> list[tuple[int, int, int, int]]:
    return [(m.command, m.result, m.target_system, m.target_component) for m in sent if m.get_type() == "COMMAND_ACK"]


PAUSE, START = mavlink.MAV_CMD_DO_PAUSE_CONTINUE, mavlink.MAV_CMD_MISSION_START
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


def test_hold_stops_the_mission_and_resume_takes_it_back(rig):
    app, fc = rig
    _run_step(app, GOOD)
    _at(app, 2.0)
    _sent(fc)
    _command(app, PAUSE, 0.0)
    sent = _sent(fc)
    assert _acks(sent) == [(PAUSE, ACCEPTED, *GCS)] and app.operator.held
    assert _mode_commands(sent) == [HOLD] and math.isfinite(app.clock.paused_since)
    _at(app, 3.0)                                     # the FC still in GUIDED (the HOLD on its way)
    setpoints = [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert setpoints and all(m.vx == 0.0 and m.vy == 0.0 for m in setpoints)   # no command while held
    _at(app, 4.0, HOLD)
    _at(app, 8.0, HOLD)                               # held: nothing takes it back
    assert _mode_commands(_sent(fc)) == [] and app.mission_time() == pytest.approx(2.0)
    _command(app, PAUSE, 1.0)
    sent = _sent(fc)
    assert _acks(sent) == [(PAUSE, ACCEPTED, *GCS)] and not app.operator.held
    assert _mode_commands(sent) == [GUIDED]
    _at(app, 9.0, GUIDED)
    _at(app, 10.0, GUIDED)
    assert not math.isfinite(app.clock.paused_since) and app.mission_time() == pytest.approx(3.0)


def test_commands_the_phase_cannot_take_and_a_strangers(rig):
    app, fc = rig
    _run_step(app, GOOD)
    _sent(fc)
    _command(app, START)                              # already running
    _command(app, mavlink.MAV_CMD_DO_SET_HOME)        # not ours to take
    _command(app, PAUSE, 0.0, ids=(77, 1))            # not an allowed ground station: no reply, no hold
    assert _acks(_sent(fc)) == [(START, mavlink.MAV_RESULT_DENIED, *GCS),
                                (mavlink.MAV_CMD_DO_SET_HOME, mavlink.MAV_RESULT_UNSUPPORTED, *GCS)]
    assert not app.operator.held
    app.machine.state = State.STARTUP
    _command(app, START)                              # start-up: engages once the average is taken
    assert _acks(_sent(fc)) == [(START, ACCEPTED, *GCS)] and app.operator.engage_allowed()


def test_the_status_a_ground_station_reads_back(rig):
    app, fc = rig
    app.params.set_value("NAV_KP", 3.0)
    _run_step(app, replace(GOOD, est_cov_en_m2=(250_000.0, 120_000.0, 640_000.0)))
    _at(app, 2.0)                                     # a tick with fresh sensors: healthy
    _sent(fc)
    app.out.heartbeat(app.state, app.failsafe_active)
    app.telemetry.operator_status()
    app.handle(_from(GCS, "PARAM_REQUEST_READ", target_system=1, target_component=191, param_id=b"NAV_DEST_LAT",
                     param_index=-1))
    reader = StatusReader(system=1, component=191)
    taken = [reader.packet(m, 100.0) for m in _sent(fc)]
    assert any(taken)
    lat, lon = app.out.estimate.position()
    assert reader.phase == "running" and reader.estimate == pytest.approx((lat, lon), abs=1e-7)
    assert reader.cov_ne_m2 == (640_000.0, 120_000.0, 250_000.0)     # north-north, north-east, east-east
    assert reader.sigma_m == 800.0 and reader.remaining_m == 70_000.0 and reader.failsafes == 0
    assert reader.params["NAV_DEST_LAT"] == pytest.approx(app.params.values["NAV_DEST_LAT"])
    lines = "\n".join(reader.lines(100.5))
    assert "phase running" in lines and "1-sigma 800 m" in lines and "70.00 km" in lines
    assert "not renewed: NAV_SYMH" in lines and "failsafes: none" in lines
    app.health.reasons = ["mag: no valid magnetometer sample for 2.5 s"]
    app.telemetry.operator_status()
    for m in _sent(fc):
        reader.packet(m, 101.0)
    assert failsafe_names(reader.failsafes) == ["mag"] and "(FAILSAFE)" in reader.lines(101.0)[0]

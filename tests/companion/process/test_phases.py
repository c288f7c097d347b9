"""Phase transitions driven by the flight controller: a reboot, a pilot's mode change."""
from __future__ import annotations

import math

from companion.app import State
from companion.io.sensors.base import SampleKind
from tests.companion.process.rig import ARMED_GUIDED, GOOD, _msg, _run_step, _sent


def test_flight_controller_reboot_restarts_the_mission(rig):
    app, fc = rig
    _run_step(app, GOOD)
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=900_000))
    assert app.state == State.RUNNING
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2_000))          # boot time went back
    assert app.state == State.STARTUP and app.restarts == 1 and app.mission is None
    assert "rebooted" in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")


def test_operator_mode_change_is_respected(rig):
    """A mode change the companion did not command pauses the mission; it does not fight back."""
    app, fc = rig
    app.params.set_value("COMP_ARM_ENABLE", 1)
    _run_step(app, GOOD)
    app.next_tick = -math.inf
    app.tick()
    _sent(fc)
    app.handle(_msg("HEARTBEAT", **{**ARMED_GUIDED, "custom_mode": 0}))        # the pilot selects MANUAL
    app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}
    app.next_tick = -math.inf
    app.tick()
    sent = _sent(fc)
    assert "FC left GUIDED (now MANUAL)" in "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")
    assert not [m for m in sent if m.get_type() == "COMMAND_LONG"]               # no GUIDED, no arm
    assert math.isfinite(app.paused_since)                                       # mission clock stopped

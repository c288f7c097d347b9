"""The failsafe response when the flight controller goes silent."""
from __future__ import annotations

import math

from tests.companion.process.rig import GOOD, FakeMission, _sent


def test_silent_flight_controller_is_judged_in_wall_time(rig):
    """No message at all: message time stands still, so only the wall clock can tell."""
    app, fc = rig
    app.mission_state.mission = FakeMission(GOOD)
    app.mission_state.command = GOOD
    start = app.link.fc.last_heartbeat_wall_s
    app.link.wall = lambda: start + 3.5                                # 3.5 s of silence (COMP_HB_TMO_S = 3)
    app.out.last_hb_sent_wall = -math.inf
    app.idle()
    assert app.failsafe_active and any("wall time" in r for r in app.health.reasons)
    texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
    assert "heartbeat" in texts
    app.next_tick = -math.inf
    app.tick()
    assert not [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]

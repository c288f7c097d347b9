"""The failsafe response when the flight controller goes silent, and not when the companion itself
was busy: the wall-time heartbeat age counts only the time the companion spent waiting on its link
(``MavlinkLink.listened_s``). The link's clock is injected; the sockets are real (the rig's)."""
from __future__ import annotations

import math

from tests.companion.process.rig import ARMED_GUIDED, GOOD, FakeMission, _msg, _sent


def test_silent_flight_controller_is_judged_in_wall_time(rig):
    """No message at all: message time stands still, so only the wall clock can tell. The companion
    waits on its real socket and nothing comes for 3.5 s of its clock (COMP_HB_TMO_S = 3)."""
    app, fc = rig
    app.mission_state.mission = FakeMission(GOOD)
    app.mission_state.command = GOOD
    now = [app.link.wall()]

    def clock() -> float:          # every reading 3.5 s on: the one wait of a spin spans 3.5 s
        now[0] += 3.5
        return now[0]

    app.link.wall = clock
    app.out.last_hb_sent_wall = -math.inf
    app.spin(0.0)
    assert app.failsafe_active and any("wall time" in r for r in app.health.reasons)
    texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
    assert "heartbeat" in texts
    app.next_tick = -math.inf
    app.tick()
    assert not [m for m in _sent(fc) if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]


def test_a_companion_blocked_past_the_timeout_does_not_call_a_streaming_flight_controller_silent(rig):
    """5 s pass on the companion's clock while it is blocked (not waiting on its socket) and the
    flight controller streams a second of ATTITUDE and its HEARTBEAT into the real socket. The
    companion then reads the queue and ticks on its first ATTITUDE, before the queued HEARTBEAT: no
    failsafe (counting all wall time since the last heartbeat, it said 'FC silent' there)."""
    app, fc = rig
    app.mission_state.mission = FakeMission(GOOD)
    app.mission_state.command = GOOD
    app.link.send_heartbeat()                     # the flight controller's socket learns our address
    assert fc.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0) is not None
    fc.write(_msg("HEARTBEAT", **ARMED_GUIDED).get_msgbuf())
    app.spin(5.0)                                 # and the companion pins the FC at its socket's address
    now = [app.link.wall()]
    app.link.wall = lambda: now[0]
    now[0] += 5.0                                 # blocked: COMP_HB_TMO_S is 3 s
    heartbeats = app.link.fc.heartbeats
    for ms in range(1100, 2001, 100):
        fc.write(_msg("ATTITUDE", time_boot_ms=ms, roll=0.0, pitch=0.0, yaw=0.5, rollspeed=0.0, pitchspeed=0.0,
                      yawspeed=0.0).get_msgbuf())
    fc.write(_msg("HEARTBEAT", **ARMED_GUIDED).get_msgbuf())
    app.next_tick = -math.inf                     # the first ATTITUDE read is a control tick
    app.out.last_hb_sent_wall = -math.inf
    app.spin(1.0)
    assert app.link.fc.heartbeats == heartbeats + 1 and app.now == 2.0     # the whole queue was read
    assert app.link.peers.impostor_frames == 0
    assert not app.failsafe_active and not app.health.reasons, app.health.reasons
    assert "silent" not in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")

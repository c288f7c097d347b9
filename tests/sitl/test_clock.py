"""sitl.clock without sockets: the lockstep gate's rules and the pacer's deadlines."""
from __future__ import annotations

import pytest

from sitl.clock import LockstepGate, Pacer, SimClock


def test_lockstep_gate_rules():
    gate = LockstepGate(0.2, timeout_s=1.0)
    assert gate.satisfied(0) and not gate.satisfied(200_000)     # at t = 0 one period of slack is free
    gate.observe(None, now_us=200_000)             # before any stamp an untimed message (HEARTBEAT) answers
    assert gate.satisfied(200_000)
    gate.finish(0.0, False)
    assert not gate.satisfied(200_000)
    gate.observe(100, now_us=200_000)              # answered up to 0.1 s >= 0.2 - 0.2
    assert gate.satisfied(200_000) and not gate.satisfied(400_000)
    gate.finish(0.0, False)
    gate.observe(None, now_us=400_000)             # after a stamp, untimed messages no longer answer
    assert not gate.satisfied(400_000)
    gate.observe(300, now_us=400_000)
    assert gate.satisfied(400_000)
    gate.finish(0.01, False)
    assert not gate.satisfied(600_000)
    gate.observe(10_000_000, now_us=600_000)       # a stamp from the future is not simulated time
    assert gate.future_stamps == 1 and gate.peer_time_ms == 300 and not gate.satisfied(600_000)
    gate.finish(1.0, True)
    assert gate.stats()["lockstep_timeouts"] == 1
    assert LockstepGate(0.2, peer=(1, 191)).eligible(1, 191) and not LockstepGate(0.2, peer=(1, 191)).eligible(255, 0)


def test_pacer_deadlines_and_rebase():
    now = [100.0]
    pacer = Pacer(10.0, rebase_after_s=0.5, clock=lambda: now[0])
    assert pacer.deadline(5_000_000) == pytest.approx(100.5)           # 5 s simulated at 10x
    now[0] = 110.0                                                      # stalled 10 s: no burst to catch up
    assert pacer.deadline(6_000_000) is None and pacer.rebases == 1
    assert pacer.deadline(7_000_000) == pytest.approx(110.1)
    assert Pacer(0.0).deadline(10**9) is None


def test_lockstep_strict_mode_and_stamped_answers():
    strict = LockstepGate(0.2, slack_periods=0)
    strict.observe(None, now_us=0)                 # before any stamp: an untimed message answers
    assert strict.satisfied(0)
    strict.finish(0.0, False)
    strict.observe(200, now_us=200_000)
    assert strict.satisfied(200_000) and not strict.satisfied(400_000)
    strict.finish(0.0, False)
    strict.observe(None, now_us=400_000)           # once stamps were seen only stamps answer
    assert not strict.satisfied(400_000)
    with pytest.raises(ValueError):
        LockstepGate(0.2, slack_periods=2)


def test_lockstep_gate_after_an_fc_reboot():
    gate = LockstepGate(0.2)
    gate.observe(599_800, now_us=600_000_000)      # the companion on the old boot, 600 s in
    assert gate.satisfied(600_000_000)
    gate.finish(0.0, False)
    gate.rebooted()                                # the boot clock restarts at 0
    assert gate.satisfied(0) and gate.satisfied(200_000) and not gate.satisfied(400_000)   # one period of slack
    for _ in range(20):                            # its backlog on the old clock answers nothing (it used to
        gate.observe(600_000, now_us=400_000)      # answer one boundary per message: a backlog of 30 s)
    assert not gate.satisfied(400_000) and gate.future_stamps == 20
    gate.observe(None, now_us=400_000)             # nor does an untimed message, after stamps
    assert not gate.satisfied(400_000)
    gate.observe(200, now_us=400_000)              # once it stamps on the new boot, its stamps answer
    assert gate.satisfied(400_000) and not gate.satisfied(600_000)


def test_sim_clock_boot_time_restarts_at_a_reboot():
    clock = SimClock(600_000_000)
    assert clock.boot_us == 600_000_000 and clock.boot_ms == 600_000
    clock.reboot()
    clock.t_us += 1_500_000
    assert (clock.time_s, clock.boot_us, clock.boot_ms) == (601.5, 1_500_000, 1_500)

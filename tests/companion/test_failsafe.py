"""Failsafe rules (pure) and live parameter changes of a running mission."""
from __future__ import annotations

import math

import numpy as np

from companion.app import apply_live_config
from companion.failsafe import Health, HealthLimits, diverged
from companion.nav.mission import Measurement, Mission
from companion.params import NavConfig, default_values

LIMITS = HealthLimits(mag_timeout_s=2.0, att_timeout_s=2.0, heartbeat_timeout_s=3.0, resume_s=1.0)
OK = dict(mag_age_s=0.1, att_age_s=0.1, hb_age_msg_s=0.5, hb_age_wall_s=0.01)


def test_each_condition_and_its_timeout():
    h = Health(LIMITS)
    assert h.evaluate(10.0, **OK) == []
    assert h.evaluate(10.0, **{**OK, "mag_age_s": 2.0}) == []                       # at the limit: still fine
    assert h.evaluate(10.0, **{**OK, "mag_age_s": 2.01})[0].startswith("mag:")
    assert h.evaluate(10.0, **{**OK, "att_age_s": math.inf})[0].startswith("attitude:")
    assert "message time" in h.evaluate(10.0, **{**OK, "hb_age_msg_s": 3.5})[0]       # FC streams, no heartbeat
    assert "wall time" in h.evaluate(10.0, **{**OK, "hb_age_wall_s": 3.5})[0]         # FC silent: clock stopped
    assert h.evaluate(10.0, **{**OK, "mag_age_s": math.nan})                           # NaN age is not healthy
    assert "(saturated)" in h.evaluate(10.0, **{**OK, "mag_age_s": 9.0}, mag_detail="saturated")[0]


def test_resume_needs_a_healthy_second():
    h = Health(LIMITS)
    h.evaluate(10.0, **{**OK, "mag_age_s": 5.0})
    assert h.entered == 1 and not h.resumed(10.0)
    h.evaluate(20.0, **OK)
    assert not h.resumed(20.5)
    h.evaluate(20.6, **{**OK, "att_age_s": 3.0})                                    # relapse restarts the wait
    h.evaluate(21.0, **OK)
    assert not h.resumed(21.9) and h.resumed(22.0)
    assert h.entered == 2


def test_latched_conditions_stay_until_cleared():
    h = Health(LIMITS)
    h.latch("params", "broken file")
    assert h.evaluate(1.0, **OK) == ["params: broken file"]
    h.evaluate(5.0, **OK)
    assert not h.resumed(5.0)
    h.clear("params")
    assert h.evaluate(6.0, **OK) == []


def test_divergence_rule():
    assert diverged(50_001.0, 50_000.0) and not diverged(49_999.0, 50_000.0) and not diverged(math.nan, 1.0)


def test_live_config_applies_weights_and_speed_but_keeps_the_mission():
    base = NavConfig.from_values(default_values())
    mission = Mission(base)
    mission.step(Measurement(0.0, -1.0, 50.0))
    changed = base.replace(speed_mps=10.0, q_d=5.0, horizon=3, dest_lat_deg=27.0, controller=0)
    deferred = apply_live_config(mission, changed)
    assert sorted(deferred) == ["NAV_CONTROLLER", "NAV_DEST_LAT"]
    assert mission.config.speed_mps == 10.0 and mission.config.q_d == 5.0 and mission.config.horizon == 3
    assert mission.config.dest_lat_deg == base.dest_lat_deg and mission.config.controller == base.controller
    assert mission.mpc.settings.horizon == 3


def test_divergence_is_judged_in_the_gaps_covariance():
    cov = np.diag([30e3 ** 2, 3e3 ** 2])                       # wide east-west, narrow north-south
    assert not diverged((60e3, 0.0), 50e3, cov)                # 2 sigma along the wide axis
    assert diverged((0.0, 60e3), 50e3, cov)                    # 20 sigma across it
    assert not diverged((0.0, 40e3), 50e3, cov)                # inside COMP_DIVERGE_KM: never
    assert diverged((0.0, 60e3), 50e3, np.full((2, 2), np.nan)) and diverged((0.0, 60e3), 50e3, None)

"""Resume after a crash (issue 10, item 7): the saved navigator state, message by message.

The closed-loop proof with a real SIGKILL is test_resume_closed_loop.py.
"""
from __future__ import annotations

import math
import pickle
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import pygeomag
import pytest
from pymavlink import mavutil

from companion.app import AppOptions, CompanionApp, State
from companion.io.sensors.base import SampleKind
from companion.nav.field import WorldMagneticModel, load_wmm, model_for_date
from companion.nav.geo import offset_position
from companion.nav.mission import Measurement, Mission
from companion.params import NavConfig, default_values
from companion.process.resume import RESUME_MAX_AGE_S, SNAPSHOT_VERSION, NavSnapshot, NavStateStore, dumps
from tests.companion.process.rig import ARMED_GUIDED, _msg, _sent
from tests.ports import free_port


def _app(tmp_path, name: str):
    port = free_port()
    fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    app = CompanionApp(AppOptions(connect=f"udpout:127.0.0.1:{port}", params=str(tmp_path / "p.parm"),
                                  log_dir=str(tmp_path / name), quiet=True, tlog=False))
    app.open()
    return app, fc


def _heard(app, t_s: float, armed_guided: bool = False) -> None:
    """The FC's first heartbeat and time stamp (message time ``t_s``), sensors fresh."""
    hb = ARMED_GUIDED if armed_guided else {**ARMED_GUIDED, "base_mode": 1, "custom_mode": 4}
    app.handle(_msg("HEARTBEAT", **hb))
    app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=int(t_s * 1000)))
    app.intake.last_valid = {SampleKind.MAG: app.now, SampleKind.ATTITUDE: app.now}


def _fly_two_steps(tmp_path):
    """A first run: a real core, its start-up step and the probe step, saved as it goes; then it dies."""
    app, fc = _app(tmp_path, "first")
    _heard(app, 1.0)
    app.machine.state = State.RUNNING
    app.mission_state.m0 = 0.0
    config = NavConfig.from_values(default_values())
    app.mission_state.mission = Mission(config)
    app.mission_state.mission_no = 1
    app.resume.new_mission()
    start = model_for_date(config.year).elements(config.start_lat_deg, config.start_lon_deg, config.alt_m, config.year)
    ned = (float(start.x_nt), float(start.y_nt), float(start.z_nt))
    app.mag.averager.add(0.5, float(start.decl_deg), float(start.incl_deg), ned)
    app.phases.step(app.now, 1.0, window_limit_s=0.0)
    app.mag.averager.add(300.0, float(start.decl_deg) + 0.01, float(start.incl_deg) - 0.01, ned)
    app.next_tick = math.inf                                            # message time on, no tick
    for ms in range(6_000, 361_001, 5_000):                             # (the clock judges jumps: it ticks on)
        app.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=ms))
    app.phases.step(app.now, 361.0)
    saved = (app.mission_state.mission.k, app.mission_state.command, np.copy(app.mission_state.mission.table3.fusion.kf.P) if hasattr(app.mission_state.mission.table3.fusion, "kf") else None,
             app.mission_state.next_step_m, app.resume.mission_id)
    app.link.close()     # no orderly close: no summary, no hold
    fc.close()
    return saved


def test_a_recent_state_resumes_the_mission_where_it_was(tmp_path):
    k, command, covariance, next_step, mission_id = _fly_two_steps(tmp_path)
    assert k == 2 and command.phase == "probe2"
    app, fc = _app(tmp_path, "second")
    try:
        _heard(app, 361.0 + RESUME_MAX_AGE_S - 10.0)                 # the FC's clock ran on meanwhile
        app.tick()
        texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
        assert "resuming mission 1 at step 1" in texts and "FAILSAFE" not in texts   # (command step 1: probe2)
        assert app.state == State.READY                              # no new start-up average
        _heard(app, 361.0 + RESUME_MAX_AGE_S - 9.0, armed_guided=True)
        app.next_tick = -math.inf
        app.tick()
        assert app.state == State.RUNNING and app.mission_state.mission_no == 1 and app.mission_state.restarts == 0
        assert app.mission_state.mission.k == k and repr(app.mission_state.command) == repr(command) and app.resume.mission_id == mission_id
        if covariance is not None:
            assert np.array_equal(app.mission_state.mission.table3.fusion.kf.P, covariance)
        assert app.mission_state.next_step_m - app.mission_state.m0 == pytest.approx(next_step)   # the step clock where it stood
        assert "resumed at step 1" in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
        assert app.summary()["resumed_from"] == "mission 1 step 1"
    finally:
        app.close()
        fc.close()


@pytest.mark.parametrize("when", ["too old", "before an FC reboot"])
def test_an_old_state_starts_a_new_mission_from_its_last_estimate(tmp_path, when):
    _, command, *_ = _fly_two_steps(tmp_path)
    app, fc = _app(tmp_path, "second")
    try:
        _heard(app, 361.0 + RESUME_MAX_AGE_S + 60.0 if when == "too old" else 50.0)
        app.tick()
        texts = "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
        assert "new mission from its last estimate" in texts
        assert app.state == State.STARTUP and app.resume.pending is None
        lat, lon, source = app.preparation.start_position()
        assert source == "last estimate" and (lat, lon) == (command.est_lat_deg, command.est_lon_deg)
        assert (lat, lon) != (app.settings.nav.start_lat_deg, app.settings.nav.start_lon_deg)   # never NAV_START mid-route
    finally:
        app.close()
        fc.close()


def test_the_store_is_atomic_and_says_why_a_file_is_unusable(tmp_path):
    store = NavStateStore(tmp_path / "s.navstate")
    assert store.load() == (None, "")
    (tmp_path / ".s.navstate.abc.tmp").write_bytes(b"half a save")       # a kill during a save
    (tmp_path / "s.navstate").write_bytes(b"\x80\x05garbage")
    snapshot, why = store.load()
    assert snapshot is None and "unreadable" in why and "s.navstate" in why
    assert not list(tmp_path.glob(".s.navstate.*.tmp"))                   # stale temporary removed
    (tmp_path / "s.navstate").write_bytes(pickle.dumps({"not": "a snapshot"}))
    assert "not a navigator state" in store.load()[1]
    # an older navigator's state is refused: its objects lack what this code reads (a version-2
    # estimator has no SYM-H reference)
    store.save(NavSnapshot(SNAPSHOT_VERSION - 1, "id", 1, 0, 0.0, 0.0, 360.0, None, 1, None, False, {}))
    snapshot, why = store.load()
    assert snapshot is None and f"version {SNAPSHOT_VERSION}" in why


def test_the_state_of_an_ended_mission_is_not_resumed(tmp_path):
    _fly_two_steps(tmp_path)
    store = NavStateStore(tmp_path / "p.navstate")
    snapshot, _ = store.load()
    store.save(replace(snapshot, finished=True))
    app, fc = _app(tmp_path, "second")
    try:
        _heard(app, 400.0)
        app.tick()
        assert "had ended" in "".join(m.text for m in _sent(fc) if m.get_type() == "STATUSTEXT")
        assert app.resume.pending is None and app.preparation.start_position()[2] == "NAV_START"
    finally:
        app.close()
        fc.close()


def _cruising_mission(model=None) -> tuple[NavSnapshot, Mission, Callable[[], Measurement]]:
    """The real-vehicle defaults' core after its probes (its snapshot, the core) and the noiseless
    measurement once its last command is flown."""
    config = NavConfig.from_values(default_values())
    mission = Mission(config, model)
    field = mission.model
    state = {"lat": config.start_lat_deg, "lon": config.start_lon_deg, "t": 0.0}

    def measure(cmd=None) -> Measurement:
        if cmd is not None:
            flown = cmd.speed_mps * config.period_s
            lat, lon = offset_position(state["lat"], state["lon"], flown * math.sin(cmd.course_rad),
                                       flown * math.cos(cmd.course_rad))
            state.update(lat=float(lat), lon=float(lon), t=state["t"] + config.period_s)
        e = field.elements(state["lat"], state["lon"], config.alt_m, config.year)
        return Measurement(state["t"], float(e.decl_deg), float(e.incl_deg), f_nt=float(e.f_nt),
                           h_nt=float(e.h_nt), z_nt=float(e.z_nt))

    cmd = mission.step(measure())
    for _ in range(4):
        cmd = mission.step(measure(cmd))
    snapshot = NavSnapshot(SNAPSHOT_VERSION, "id", 1, 0, state["t"], state["t"], state["t"] + config.period_s, cmd,
                           config.elements, None, False, mission.snapshot())
    return snapshot, mission, lambda: measure(cmd)


def test_a_shipped_field_model_is_saved_by_its_name_and_the_core_flies_on_the_same(tmp_path):
    """The filters' field model is not state: saved as the name it loads by, it comes back as the
    very model (not a 239 kB copy in every file), and the core restored from the file steps bit
    for bit as one restored from the whole pickle did."""
    snapshot, mission, measurement = _cruising_mission()
    store = NavStateStore(tmp_path / "deep" / "s.navstate")   # (its folder made on the first save)
    store.save(snapshot)
    whole = pickle.dumps(snapshot, protocol=pickle.HIGHEST_PROTOCOL)
    saved = store.path.read_bytes()
    assert len(saved) < len(whole) - len(pickle.dumps(mission.model)) // 2
    by_name, loaded = store.load()[0].mission(), pickle.loads(whole).mission()
    assert by_name.estimator.model is by_name.model is load_wmm(mission.model.name)
    meas = measurement()
    for _ in range(3):
        a, b = by_name.step(meas), loaded.step(meas)
        assert replace(a, solver_time_s=0.0) == replace(b, solver_time_s=0.0)
        meas = replace(meas, time_s=meas.time_s + mission.config.period_s)


def test_any_other_field_model_is_saved_whole(tmp_path):
    model = WorldMagneticModel.from_cof(Path(pygeomag.__file__).parent / "wmm" / "WMM_2020.COF",
                                        allow_extrapolation=True)
    snapshot, _, _ = _cruising_mission(model)
    back = pickle.loads(dumps(snapshot)).mission_state["estimator"].model
    assert back is not model and back.allow_extrapolation and back.name == model.name
    assert np.array_equal(back._sums._coeffs, model._sums._coeffs)

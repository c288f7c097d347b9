"""The sensor and world models the stand-in is built on, without sockets: rotations, noise, quantisation, the FC's solution, the truth field."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.frames import body_to_ned, ned_to_body
from sitl.scenario import load_scenario
from sitl.sensors import Attitude, NavSolution, Normals, SensorSuite
from sitl.world.build import StormUnavailableError, build_truth_field
from sitl.world.ins import InsErrorConfig


def test_rotations_and_noise_reproducible():
    rng = np.random.default_rng(0)
    for _ in range(20):
        r, p, y = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-3, 3)
        v = rng.normal(size=3)
        assert np.allclose(body_to_ned(ned_to_body(v, r, p, y), r, p, y), v)
    # level, facing east: north is on the left (-y), down stays down
    assert np.allclose(ned_to_body((0.0, 1.0, 0.0), 0.0, 0.0, math.pi / 2), (1.0, 0.0, 0.0))
    a, b = Normals(np.random.default_rng(5), block=7), Normals(np.random.default_rng(5), block=7)
    assert [a() for _ in range(30)] == [b() for _ in range(30)]


def test_sensor_suite_quantises_and_adds_bias():
    model = load_scenario("paper_pacific").sensors
    from dataclasses import replace
    model = replace(model, mag_noise_nt=0.0, mag_bias_nt=(150.0, 0.0, -250.0), mag_lsb_nt=100.0)
    suite = SensorSuite(model, np.random.default_rng(1))
    x, y, z = suite.sample_mag((30000.0, -2000.0, 29400.0), Attitude(0.0, 0.0, 0.0))
    assert (x, y, z) == (30200.0, -2000.0, 29200.0)                     # 30150 rounds to even hundreds
    x, y, z = suite.sample_mag((30000.0, 0.0, 0.0), Attitude(0.0, 0.0, math.pi / 2), extra_nt=1000.0)
    assert (x, y, z) == (1200.0, -29000.0, 800.0)


def test_nav_solution_aided_then_inertial():
    nav = NavSolution(InsErrorConfig(deterministic=True), np.random.default_rng(0), aided_noise_m=0.5)
    nav.update(0.0, True, 33.0, 0.0, 10.0)
    lat, lon = nav.position(0.0, 33.0, 152.0)
    assert abs(lat - 33.0) < 1e-4 and not nav.inertial
    nav.update(10.0, False, 33.0, 0.0, 10.0)                            # GPS lost: Table 1 errors appear
    lat, lon = nav.position(10.0, 33.0, 152.0)
    assert nav.inertial and (lat - 33.0) * 110_900 == pytest.approx(5000.0, rel=0.01)
    e1 = nav.error_m(12.0, 33.0, 152.0)
    e2 = nav.error_m(14.0, 33.0, 152.0)                                 # moves smoothly between propagations
    assert e1 != e2 and abs(e2[0] - e1[0]) < 30.0


def test_build_truth_field_quiet_is_wmm_and_storm_errors_are_clear(tmp_path):
    sc = load_scenario("paper_pacific")
    truth = build_truth_field(sc)
    wmm = truth.model.elements(33.0, 152.0, 0.0, sc.year)
    assert np.allclose(truth.field_ned_nt(33.0, 152.0, 0.0, 123.0), (wmm.x_nt, wmm.y_nt, wmm.z_nt))
    with pytest.raises(StormUnavailableError, match="storm data"):
        build_truth_field(load_scenario("paper_long_storm"), data_dir=tmp_path)

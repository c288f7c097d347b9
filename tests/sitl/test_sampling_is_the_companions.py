"""The Monte Carlo's vectorised sample path forms the period record the companion forms.

:func:`sitl.world.sampling.average_samples` (a whole period at once, numpy) and the companion's own
magnetometer pipeline (:class:`companion.nav.magnetometer.MagProcessor`: attitude, specific force and
field one sample at a time, tilt compensation, the settling wait after a new command, the
averager) are given the same samples, simulated in the realistic Pacific world with its
calibration residuals, wave motion, attitude errors and accelerometer noise; every field of the
two :class:`companion.nav.period.PeriodAverage` records agrees to 1e-9.
"""
from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from companion.nav.magnetometer import AttitudeState, MagProcessor
from companion.nav.navigator import SETTLE_AFTER_COMMAND_S
from sitl.scenario import load_scenario
from sitl.sensors import WaveMotion
from sitl.world.magerrors import MagErrors
from sitl.world.sampling import PeriodKnots, SampleSettings, average_samples, simulate_samples


def _companions_average(samples, settle_until_s: float):
    """The companion's pipeline on ``samples``, one sample at a time as MAVLink would bring them."""
    mag = MagProcessor(settle_until_s=settle_until_s)
    for k, t in enumerate(samples.time_s.tolist()):
        mag.add_attitude(AttitudeState(t, float(samples.roll_rad[k]), float(samples.pitch_rad[k]),
                                       float(samples.yaw_rad[k])))
        mag.add_specific_force(t, tuple(samples.force_body_mps2[k].tolist()), (0.0, 0.0, 0.0))
        mag.add_mag(t, tuple(samples.mag_body_nt[k].tolist()))
    assert mag.stats.accepted == len(samples.time_s)
    return mag.take(float(samples.time_s[-1]))


@pytest.mark.parametrize("settled", [False, True], ids=["holding course", "after a new command"])
def test_the_vectorised_period_is_the_companions_record(settled: bool):
    scenario = load_scenario("pacific")
    sensors = scenario.sensors
    rng = np.random.default_rng(7)
    times = 1000.0 + 30.0 * np.arange(13)       # one 360 s period, 30 s sub-steps, a turn at its start
    course = np.radians(np.r_[40.0, np.full(12, 130.0)])
    ned = np.array([27000.0, -1800.0, 30000.0]) + 50.0 * rng.standard_normal((13, 3))
    knots = PeriodKnots(times, ned, course, 1e-3 * rng.standard_normal((13, 3)), np.full(13, math.nan))
    settings = SampleSettings(sensors.mag_rate_hz, sensors.mag_noise_nt, sensors.mag_lsb_nt, sensors.mag_bias_nt,
                              sensors.attitude_noise_deg, "ins", 0.05)
    errors = MagErrors.draw(sensors.mag_errors, np.random.default_rng(3))
    samples = simulate_samples(knots, settings, WaveMotion().tilt_rad, errors.apply, rng, np.random.default_rng(4))
    settle = times[0] + SETTLE_AFTER_COMMAND_S if settled else -math.inf

    vectorised, companion = average_samples(samples, settle), _companions_average(samples, settle)

    # samples at t0 + 0.1 k s, k = 1 ... 3600: those from t0 + 60 s on (k >= 600) are gravity samples after a turn
    assert companion.grav_count == (3001 if settled else 3600) and vectorised.count == companion.count == 3600
    for f in fields(companion):
        got, want = getattr(vectorised, f.name), getattr(companion, f.name)
        assert np.allclose(got, want, rtol=0.0, atol=1e-9), f"{f.name}: {got!r} against the companion's {want!r}"
    assert math.isfinite(companion.incl_grav_deg) and math.isfinite(companion.mag_heading_deg)

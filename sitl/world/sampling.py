"""One control period of magnetometer and attitude samples, simulated and averaged (vectorised).

What the in-process Monte Carlo runs in the realistic world, so it sees what the companion
sees from the MAVLink simulator (:class:`sitl.sensors.SensorSuite` draws the same errors one
sample at a time), sample by sample rather than as an analytic averaged draw:

1. sample times ``t_j`` at ``rate_hz`` over the period; the true field at each sample
   interpolated linearly in time between the kinematic sub-steps (``knot``s, 30 s apart by
   default: a few hundred metres, far below the crustal field's correlation length);
2. true attitude: the wave roll/pitch at ``t_j`` and yaw = course over ground of the sub-step;
   the body field ``b = C_bn B``, then the run's calibration residuals
   (:class:`sitl.world.magerrors.MagErrors`), the fixed bias, white noise per axis,
   quantisation to ``lsb_nt``;
3. the flight controller's attitude: true plus the slow errors of the sub-step (biases, heading
   drift, INS tilt and azimuth errors, :class:`sitl.world.attitude.AttitudeErrors`) plus white
   noise; for the ``magnetic`` source the yaw is the compass yaw of the sample's calibrated
   field against the declination table at the flight controller's position
   (:func:`sitl.world.attitude.compass_yaw_rad`);
4. the companion's processing (:mod:`companion.nav.magnetometer`): the measured body field
   rotated into NED with the reported attitude; the samples from ``settle_until_s`` on (the
   companion's wait after a new command, :data:`companion.nav.navigator.SETTLE_AFTER_COMMAND_S`)
   are gravity and heading samples, with the specific force. All go into the companion's own
   averager (:meth:`companion.nav.period.PeriodAverager.add_samples`), which gives the period's
   record, :class:`companion.nav.period.PeriodAverage`, exactly as the companion forms it from the
   same samples one at a time (tested to 1e-9).

Pure: arrays and a seeded generator in, averages out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from companion.frames import mats_nb_from_euler
from companion.nav.period import PeriodAverage, PeriodAverager
from sitl.world.attitude import compass_yaw_rad

__all__ = ["STANDARD_GRAVITY", "PeriodKnots", "PeriodSamples", "SampleSettings", "average_samples", "sample_period",
           "simulate_samples"]


@dataclass(frozen=True)
class SampleSettings:
    """Per-sample sensor settings (from :class:`sitl.scenario.SensorModel`)."""

    rate_hz: float
    mag_noise_nt: float
    mag_lsb_nt: float
    mag_bias_nt: tuple[float, float, float]
    attitude_noise_deg: float
    heading_source: str = "true"
    accel_noise_mps2: float = 0.0


@dataclass(frozen=True)
class PeriodKnots:
    """The kinematic sub-steps of one period (K >= 2 knots, the first at the period's start).

    ``field_ned_nt`` (K, 3) true field; ``course_rad`` (K,) yaw over the sub-step ending at each
    knot; ``slow_error_rad`` (K, 3) roll/pitch/yaw slow errors; ``decl_table_deg`` (K,) the
    flight controller's table declination at its position (NaN unless magnetic).
    """

    time_s: np.ndarray
    field_ned_nt: np.ndarray
    course_rad: np.ndarray
    slow_error_rad: np.ndarray
    decl_table_deg: np.ndarray


STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class PeriodSamples:
    """One period's samples as the companion receives them: times (N,), the measured body field
    (N, 3) nT, the flight controller's attitude (N,) each, rad, and the specific force (N, 3) m/s^2."""

    time_s: np.ndarray
    mag_body_nt: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    yaw_rad: np.ndarray
    force_body_mps2: np.ndarray


def sample_period(knots: PeriodKnots, settings: SampleSettings, tilt_rad: Callable[[np.ndarray], tuple],
                  mag_apply: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                  rng: np.random.Generator, accel_rng: np.random.Generator | None = None,
                  settle_until_s: float = -math.inf) -> PeriodAverage:
    """Simulate and average the samples of one period (see the module docstring):
    :func:`average_samples` of :func:`simulate_samples`."""
    return average_samples(simulate_samples(knots, settings, tilt_rad, mag_apply, rng, accel_rng), settle_until_s)


def simulate_samples(knots: PeriodKnots, settings: SampleSettings, tilt_rad: Callable[[np.ndarray], tuple],
                     mag_apply: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                     rng: np.random.Generator, accel_rng: np.random.Generator | None = None) -> PeriodSamples:
    """The samples of one period (steps 1-3 of the module docstring).

    ``tilt_rad(t)`` gives the true (roll, pitch) arrays at sample times; ``mag_apply(body, t)``
    the calibration residuals (None: none). Draws 3 magnetometer then 3 attitude normals per
    sample, as one (N, 6) block; the accelerometer's white noise (``accel_noise_mps2``) comes from
    ``accel_rng``, so the other draws stay as they were without it.
    """
    t0, t1 = float(knots.time_s[0]), float(knots.time_s[-1])
    count = max(1, int(round((t1 - t0) * settings.rate_hz))) if t1 > t0 else max(1, int(round(settings.rate_hz)))
    if t1 > t0:
        t = t0 + (np.arange(count) + 1.0) * (t1 - t0) / count
        field = np.stack([np.interp(t, knots.time_s, knots.field_ned_nt[:, i]) for i in range(3)], -1)
        index = np.clip(np.searchsorted(knots.time_s, t, side="left"), 1, len(knots.time_s) - 1)
    else:   # stationary start-up average at one point
        t = t0 + (np.arange(count) + 1.0) / settings.rate_hz
        field = np.repeat(knots.field_ned_nt[:1], count, axis=0)
        index = np.zeros(count, dtype=int)
    roll, pitch = tilt_rad(t)
    yaw = knots.course_rad[index]
    c_nb = mats_nb_from_euler(roll, pitch, yaw)
    body = np.einsum("nji,nj->ni", c_nb, field)                 # C_bn B = C_nb^T B
    clean = mag_apply(body, t) if mag_apply is not None else body
    noise = rng.standard_normal((count, 6))
    meas = clean + np.asarray(settings.mag_bias_nt, float) + settings.mag_noise_nt * noise[:, :3]
    if settings.mag_lsb_nt > 0.0:
        meas = np.round(meas / settings.mag_lsb_nt) * settings.mag_lsb_nt
    sat = math.radians(settings.attitude_noise_deg)
    slow = knots.slow_error_rad[index]
    roll_est = roll + slow[:, 0] + sat * noise[:, 3]
    pitch_est = pitch + slow[:, 1] + sat * noise[:, 4]
    if settings.heading_source == "magnetic":
        yaw_est = compass_yaw_rad(clean, roll_est, pitch_est, knots.decl_table_deg[index]) + sat * noise[:, 5]
    else:
        yaw_est = yaw + slow[:, 2] + sat * noise[:, 5]
    # the specific force f = -g times the body's down axis (the waves' accelerations average out)
    # plus white noise
    force = -STANDARD_GRAVITY * c_nb[:, 2, :]
    if settings.accel_noise_mps2 > 0.0 and accel_rng is not None:
        force = force + settings.accel_noise_mps2 * accel_rng.standard_normal(force.shape)
    return PeriodSamples(t, meas, roll_est, pitch_est, yaw_est, force)


def average_samples(samples: PeriodSamples, settle_until_s: float = -math.inf) -> PeriodAverage:
    """The companion's processing of a period's samples (step 4 of the module docstring), vectorised:
    the field rotated into NED with the reported attitude; the samples from ``settle_until_s`` on
    gravity and heading samples; all into the companion's averager."""
    t, meas, force = samples.time_s, samples.mag_body_nt, samples.force_body_mps2
    count = len(t)
    c_nb_est = mats_nb_from_euler(samples.roll_rad, samples.pitch_rad, samples.yaw_rad)
    ned = np.einsum("nij,nj->ni", c_nb_est, meas)
    steady = t >= settle_until_s
    dot, force_ned, body, body_force = (np.full((count, k), np.nan) for k in (1, 3, 3, 3))
    dot[steady, 0] = np.einsum("ni,ni->n", meas[steady], force[steady])
    force_ned[steady] = np.einsum("nij,nj->ni", c_nb_est[steady], force[steady])
    body[steady], body_force[steady] = meas[steady], force[steady]
    averager = PeriodAverager()
    averager.add_samples(t, ned, dot[:, 0], force_ned, body, body_force)
    return averager.take(float(t[-1]))

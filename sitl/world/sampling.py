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
   rotated into NED with the reported attitude, D, I, H, Z and F per sample, averaged over the
   period (D unwrapped around the first sample): :class:`AveragedElements`, with each average's
   standard error from the period's own scatter, ``1.4826 MAD / sqrt(n)`` as the companion
   measures it (:func:`companion.nav.inclination.robust_standard_error`); and the magnetic
   heading of the period's steady part (after the first ``SETTLE_S``), levelled by gravity from
   the mean body field, as the companion measures it (:func:`companion.nav.heading.levelled_heading_deg`),
   and the gravity-referenced I of the same samples (:func:`companion.nav.inclination.ratio_inclination_deg`),
   which the companion navigates on with a heading-free element set.

Pure: arrays and a seeded generator in, averages out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from companion.nav.heading import levelled_heading_deg
from companion.nav.inclination import mad_standard_errors, ratio_inclination_deg
from sitl.world.attitude import compass_yaw_rad

__all__ = ["AveragedElements", "PeriodKnots", "SampleSettings", "elements_from_ned", "robust_standard_errors",
           "sample_period", "rotation_nb"]


@dataclass(frozen=True)
class AveragedElements:
    """Field elements averaged over one control period, as the companion forms them.

    ``decl_deg``, ``incl_deg`` in degrees; ``f_nt`` total intensity, ``h_nt`` horizontal
    intensity, ``z_nt`` vertical (down) component, all nT; ``samples`` averaged; ``time_s`` the
    end of the period.
    """

    time_s: float
    decl_deg: float
    incl_deg: float
    f_nt: float
    h_nt: float
    z_nt: float
    samples: int
    decl_se_deg: float = math.nan
    incl_se_deg: float = math.nan
    f_se_nt: float = math.nan
    h_se_nt: float = math.nan
    z_se_nt: float = math.nan
    mag_heading_deg: float = math.nan
    incl_grav_deg: float = math.nan
    incl_grav_se_deg: float = math.nan


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


def rotation_nb(roll, pitch, yaw) -> np.ndarray:
    """Body -> NED rotation matrices (..., 3, 3) of ZYX Euler angles (``companion.frames``)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    c = np.empty(np.broadcast(cr, cp, cy).shape + (3, 3))    # filled in place: nested np.stack copied it twice
    srsp, crsp = sr * sp, cr * sp        # the products in the order they had: results bit for bit
    c[..., 0, 0], c[..., 0, 1], c[..., 0, 2] = cp * cy, srsp * cy - cr * sy, crsp * cy + sr * sy
    c[..., 1, 0], c[..., 1, 1], c[..., 1, 2] = cp * sy, srsp * sy + cr * cy, crsp * sy - sr * cy
    c[..., 2, 0], c[..., 2, 1], c[..., 2, 2] = -sp, sr * cp, cr * cp
    return c


STANDARD_GRAVITY = 9.80665
SETTLE_S = 60.0     # the companion's gravity samples wait this long after a new command (its SETTLE_AFTER_COMMAND_S)


def robust_standard_errors(values: np.ndarray) -> np.ndarray:
    """``1.4826 MAD / sqrt(n)`` of each column of ``values`` (N, k), the companion's own
    :func:`companion.nav.inclination.mad_standard_error`; NaN below two samples."""
    return mad_standard_errors(np.ascontiguousarray(np.asarray(values, dtype=float).T))


def elements_from_ned(ned: np.ndarray, time_s: float) -> AveragedElements:
    """Average per-sample D, I, F, H, Z of NED vectors (N, 3), D unwrapped around the first,
    with the standard error of each average from the samples' scatter."""
    n, e, d = ned[:, 0], ned[:, 1], ned[:, 2]
    h = np.hypot(n, e)
    decl = np.degrees(np.arctan2(e, n))
    decl = decl[0] + (decl - decl[0] + 180.0) % 360.0 - 180.0
    per_sample = np.stack([decl, np.degrees(np.arctan2(d, h)), np.sqrt(n * n + e * e + d * d), h, d], -1)
    means = per_sample.mean(axis=0)
    se = robust_standard_errors(per_sample)
    return AveragedElements(time_s, *(float(v) for v in means), len(n), *(float(v) for v in se))


def sample_period(knots: PeriodKnots, settings: SampleSettings, tilt_rad: Callable[[np.ndarray], tuple],
                  mag_apply: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                  rng: np.random.Generator, accel_rng: np.random.Generator | None = None) -> AveragedElements:
    """Simulate and average the samples of one period (see the module docstring).

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
    c_nb = rotation_nb(roll, pitch, yaw)
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
    c_nb_est = rotation_nb(roll_est, pitch_est, yaw_est)
    ned = np.einsum("nij,nj->ni", c_nb_est, meas)
    # the gravity samples as the companion takes them: the period's steady part, the specific force
    # f = -g times the body's down axis (the waves' accelerations average out) plus white noise
    steady = t >= t0 + SETTLE_S if t1 - t0 > 2.0 * SETTLE_S else np.ones(count, dtype=bool)
    force = -STANDARD_GRAVITY * c_nb[steady, 2, :]
    if settings.accel_noise_mps2 > 0.0 and accel_rng is not None:
        force = force + settings.accel_noise_mps2 * accel_rng.standard_normal(force.shape)
    mag = meas[steady]
    force_ned = np.einsum("nij,nj->ni", c_nb_est[steady], force)
    incl_grav, incl_grav_se = ratio_inclination_deg(np.einsum("ni,ni->n", mag, force), ned[steady], force_ned)
    return replace(elements_from_ned(ned, t1), mag_heading_deg=levelled_heading_deg(mag.mean(axis=0), force.mean(axis=0)),
                   incl_grav_deg=incl_grav, incl_grav_se_deg=incl_grav_se)

"""The period's gravity-referenced inclination, and the standard error of a period's average.

Pure: sequences (or arrays) of per-sample values in, numbers out.

**The period's I_g is a ratio of averages, not an average of per-sample angles.** Per sample,
``asin(-m.f / (|m||f|))`` (:func:`companion.nav.magnetometer.gravity_inclination_deg`) divides
by noisy norms: with white noise ``E|f|`` is inflated by about ``(sigma_x^2 + sigma_y^2) / (2g)``
(the axes across gravity) and ``E|m|`` likewise across the field, and the average of the
nonlinear angle keeps that bias however many samples there are. At PX4 SIH's noise
(magnetometer 2000/2000/3000 nT, accelerometer 0.5/1.7/1.4 m/s^2 per axis while armed) that is
-0.15 deg with the accelerometer quiet and -0.6 to -0.9 deg with it shaking (synthetic, I = 40
deg; measured on SIH: -0.4 deg driving), a bias the start-up calibration, taken standing,
cannot remove. The period's estimate is instead

    I_g = asin(-mean(m . f) / (|mean(m_NED)| |mean(f_NED)|))

over the gravity samples: ``m . f`` is linear in each sensor's noise and rotation-invariant, so
its mean is unbiased under independent white noise whatever the attitude does; the norms are
taken of the *means* (the noise averages out first: a bias of order ``sigma^2 / (n F)``). The
means are taken in NED with the attitude at each sample's time, so a body turning in yaw or
rolling in waves does not shorten them (a body-frame mean of ``f`` would be ``g E[cos roll]``:
0.4 deg of I for a boat rolling +-10 deg). The norm of a mean is invariant to a constant heading
error, and to any constant attitude error while the course is held, so the flight controller's
attitude enters only through its error's variation within the period, at second order (a 2.2
deg tilt error turning 50 deg with the body: 0.0045 deg of I). ``sqrt(mean |m|^2 - 3 sigma^2)``
would need the noise declared, and a wrong declaration is a bias again. Noise-free, the
estimate equals the per-sample average wherever the field and the tilt are constant.

The tilt-compensated I and D and the intensity F (mean of the per-sample ``|m|``) keep their
per-sample averages: with magnetometer noise alone they carry a constant bias (at SIH's noise
about -0.15 deg of I and +140 nT of F, ``~sigma^2 / F``) that does not change when the vehicle
drives, so the start-up calibration (NAV_CALIBRATE) removes it.

**Standard errors.** Each average carries its standard error from the period's own scatter,
``1.4826 MAD / sqrt(n)`` (the median absolute deviation: a few spikes that passed the spike
filter do not widen it, the way they would a standard deviation); for I_g the scatter is that of
each sample's first-order influence on the ratio (the delta method). Measured, not declared: on
SIH the accelerometer's shaking, not the magnetometer, dominates I_g's scatter (per sample about
10 deg), which no magnetometer noise parameter would describe. Samples are taken as independent
(vibration correlated over many samples would make the error larger than said).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["MAD_TO_SIGMA", "mad_standard_error", "mad_standard_errors", "ratio_inclination_deg",
           "robust_standard_error"]

MAD_TO_SIGMA = 1.482602218505602   # 1 / Phi^-1(3/4): the MAD of a normal sample is 0.6745 sigma


def _partition_medians(values: np.ndarray) -> np.ndarray:
    """np.median along the last axis of an array without NaN, by np.partition: the same numbers
    without median's per-call checks (a quarter of a period's averaging went there)."""
    mid = values.shape[-1] // 2
    if values.shape[-1] % 2:
        return np.partition(values, mid, axis=-1)[..., mid]
    part = np.partition(values, (mid - 1, mid), axis=-1)
    return (part[..., mid - 1] + part[..., mid]) / 2.0


def mad_standard_errors(rows: np.ndarray) -> np.ndarray:
    """:func:`mad_standard_error` of each row of a 2-D array, in one partition per median (the
    same numbers, bit for bit, as row by row); NaN for a row with a NaN, all NaN below two columns.

    >>> mad_standard_errors(np.array([[1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 2.0, math.nan]]))
    array([0.74130111,        nan])
    """
    r = np.asarray(rows, dtype=float)
    if r.ndim != 2:
        raise ValueError(f"mad_standard_errors needs a 2-D array of rows, got shape {r.shape}")
    if r.shape[1] < 2:
        return np.full(r.shape[0], math.nan)
    out = MAD_TO_SIGMA * _partition_medians(np.abs(r - _partition_medians(r)[:, None])) / math.sqrt(r.shape[1])
    out[np.isnan(r).any(axis=1)] = math.nan     # partition sorted the NaN last: that row's median is not one
    return out


def mad_standard_error(values: np.ndarray) -> float:
    """``1.4826 MAD / sqrt(n)`` of a 1-D array (NaN below two values or with a NaN among them).

    >>> mad_standard_error(np.array([1.0, 2.0, 3.0, 4.0]))   # MAD 1
    0.741301109252801
    """
    return float(mad_standard_errors(np.asarray(values, dtype=float).reshape(1, -1))[0])


def robust_standard_error(values: Sequence[float]) -> float:
    """``1.4826 MAD / sqrt(n)``: the standard error of the mean of ``values`` (NaN below 2 values
    or with a NaN among them), :func:`mad_standard_error` for any sequence.

    >>> robust_standard_error([1.0, 2.0, 3.0, 4.0])   # MAD 1
    0.741301109252801
    >>> robust_standard_error([0.0, 1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 1.0, -1.0, 500.0]) < 0.5
    True
    """
    return mad_standard_error(np.asarray(list(values), dtype=float))


def ratio_inclination_deg(dots, mag_ned, force_ned) -> tuple[float, float]:
    """``(I_g, its standard error)`` in degrees, NaN without samples or with a zero mean.

    ``dots``: ``m . f`` per sample (body frame, nT m/s^2); ``mag_ned``, ``force_ned``: the field and
    the specific force per sample in NED (sequences of triples or (N, 3) arrays).
    ``I_g = asin(-mean(m.f) / (|mean m| |mean f|))``.

    >>> incl, se = ratio_inclination_deg([-20000.0 * 9.81] * 2, [(20000.0, 0.0, 20000.0)] * 2,
    ...                                  [(0.0, 0.0, -9.81)] * 2)
    >>> round(incl, 9), se
    (45.0, 0.0)
    """
    d = np.asarray(dots, dtype=float).reshape(-1)
    n = d.size
    if n == 0:
        return math.nan, math.nan
    mv = np.asarray(mag_ned, dtype=float).reshape(n, 3)
    fv = np.asarray(force_ned, dtype=float).reshape(n, 3)
    dot, m, f = float(d.mean()), mv.mean(axis=0), fv.mean(axis=0)
    m_norm, f_norm = float(np.linalg.norm(m)), float(np.linalg.norm(f))
    if not (m_norm > 0.0 and f_norm > 0.0 and math.isfinite(m_norm * f_norm)):
        return math.nan, math.nan
    sine = max(-1.0, min(1.0, -dot / (m_norm * f_norm)))
    incl = math.degrees(math.asin(sine))
    if n < 2 or abs(sine) >= 1.0:
        return incl, math.nan
    # each sample's first-order influence on the sine: d(-dot/(|M||F|)) with |M| and |F| moving
    # along their means' directions
    influence = (-(d - dot) / (m_norm * f_norm) - sine * ((mv - m) @ (m / m_norm)) / m_norm
                 - sine * ((fv - f) @ (f / f_norm)) / f_norm)
    se_sine = mad_standard_error(influence)
    return incl, math.degrees(se_sine / math.sqrt(1.0 - sine * sine))

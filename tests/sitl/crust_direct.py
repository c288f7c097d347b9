"""An independent direct sum of a Schmidt semi-normalised field model at one point (numpy, by
degree, the standard recursion of the WMM technical report's eq. for P_n^m)."""
from __future__ import annotations

import math

import numpy as np

WGS84_A_M = 6378137.0
WGS84_E2 = (1.0 / 298.257223563) * (2.0 - 1.0 / 298.257223563)


def direct_ned_nt(gh: np.ndarray, min_degree: int, max_degree: int, lat_deg: float, lon_deg: float,
                  alt_m: float = 0.0, radius_m: float = 6371200.0) -> np.ndarray:
    """(X, Y, Z) in nT, geodetic north/east/down, of ``gh[:, n, m]`` summed over min..max degree."""
    phi = math.radians(lat_deg)
    nu = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(phi) ** 2)
    p, z = (nu + alt_m) * math.cos(phi), (nu * (1.0 - WGS84_E2) + alt_m) * math.sin(phi)
    r = math.hypot(p, z)
    lat_c = math.atan2(z, p)
    theta = math.pi / 2.0 - lat_c
    ct, st = math.cos(theta), math.sin(theta)
    m = np.arange(max_degree + 1, dtype=float)
    cos_ml, sin_ml = np.cos(m * math.radians(lon_deg)), np.sin(m * math.radians(lon_deg))
    # P_m^m (Schmidt): P_0^0 = 1, P_1^1 = sin, P_m^m = sqrt((2m - 1) / 2m) sin P_(m-1)^(m-1)
    pmm = np.ones(max_degree + 1)
    for k in range(1, max_degree + 1):
        pmm[k] = pmm[k - 1] * st * (1.0 if k == 1 else math.sqrt((2 * k - 1) / (2 * k)))
    p_prev2 = np.zeros(max_degree + 1)
    p_prev = np.zeros(max_degree + 1)   # P_(n-1)^m
    b_r = b_t = b_p = 0.0
    for n in range(0, max_degree + 1):
        p_n = np.zeros(max_degree + 1)
        p_n[n] = pmm[n]
        ms = m[:n]
        if n >= 1:
            p_n[:n] = ((2 * n - 1) * ct * p_prev[:n] - np.sqrt(np.maximum((n - 1) ** 2 - ms ** 2, 0.0)) * p_prev2[:n]) \
                / np.sqrt(n * n - ms ** 2)
        if n >= min_degree:
            mm = m[: n + 1]
            dp = (n * ct * p_n[: n + 1] - np.sqrt(n * n - mm ** 2) * np.append(p_prev[:n], 0.0)) / st
            g, h = gh[0, n, : n + 1], gh[1, n, : n + 1]
            ratio = (radius_m / r) ** (n + 2)
            in_phase = g * cos_ml[: n + 1] + h * sin_ml[: n + 1]
            b_r += ratio * (n + 1) * float(in_phase @ p_n[: n + 1])
            b_t -= ratio * float(in_phase @ dp)
            b_p += ratio * float((mm * (g * sin_ml[: n + 1] - h * cos_ml[: n + 1])) @ p_n[: n + 1]) / st
        p_prev2, p_prev = p_prev, p_n
    psi = lat_c - phi
    x_c, z_c = -b_t, -b_r
    return np.array([x_c * math.cos(psi) - z_c * math.sin(psi), b_p, x_c * math.sin(psi) + z_c * math.cos(psi)])

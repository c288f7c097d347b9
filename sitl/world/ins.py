"""INS error model (truth side), PSINS-like: how far the inertial solution drifts from the truth.

State (15, the order of the paper's eq. 47 and of PSINS):
``phi_e, phi_n, phi_u`` platform misalignment (rad), ``dv_e, dv_n, dv_u`` velocity error
(m/s), ``dlat, dlon, dh`` position error (rad, rad, m), ``eps_c`` constant gyro drift and
``eps_r`` first-order Markov gyro drift (rad/s), east/north/up.

Dynamics: the linearised strapdown error equations in a local-level ENU frame on a
rotating Earth (Titterton & Weston ch. 12; PSINS ``etm``): misalignment driven by gyro
drift, Earth and transport rate; velocity error driven by specific force crossed with the
misalignment (the Schuler loop) and Coriolis terms; position error by velocity error.
The vertical channel is held (Table 1: vertical error 0), as a baro-aided INS does.

What we integrate and why: PSINS mechanises at 0.01 s (Table 2). For a vehicle holding
course and speed the error equations are linear with coefficients that change only with
latitude and velocity, so we propagate them *exactly* over each step with the matrix
exponential of the error dynamics (coefficients frozen over the step, re-evaluated every
step). The error growth (Schuler oscillation, 84 min; Earth-rate coupling; gyro-drift
growth) is the same as a 0.01 s mechanisation to within the coefficient freeze, at a
thousandth of the cost. The random drift is sampled exactly for the Markov process.

The exponential acts on the state only, so it is applied as a vector: ``expm(F T) x`` by a
8-term Taylor series in Horner form (:func:`expm_times`), on pieces of at most 30 s (the
in-process sub-step). F is badly scaled (g T ~ 300 against 1/R ~ 1e-7), yet its spectrum is
small (Schuler and Earth rate, |lambda T| < 0.04 per piece), so the series converges to
rounding within 8 terms; measured against a 60-term series in extended precision it is
accurate to 4e-16 of ``|Phi| |x|``, where scipy's Pade ``expm`` of the same matrix (used here
before) is off by up to 1e-6 of it (tests), at 2.3 times the cost.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from companion.nav.geo import radii_of_curvature_m
from sitl.world.checks import require

__all__ = ["InsErrorConfig", "InsErrorModel", "expm_times", "expm_times_stacked", "propagate_together"]

TAYLOR_TERMS = 8
TAYLOR_PIECE_S = 30.0


def expm_times(f: np.ndarray, dt_s: float, x: np.ndarray) -> np.ndarray:
    """``expm(F dt) x`` for the INS error dynamics: Horner's form of the Taylor series,
    ``x + A (x + A/2 (x + ... (x + A/8 x)))`` with ``A = F dt / pieces``, applied ``pieces`` times
    (``dt / pieces`` at most :data:`TAYLOR_PIECE_S`); see the module docstring for its accuracy.
    One model is a stack of one (:func:`expm_times_stacked`)."""
    return expm_times_stacked(f[None], dt_s, x[None])[0]


def expm_times_stacked(f: np.ndarray, dt_s: float, x: np.ndarray) -> np.ndarray:
    """:func:`expm_times` of a stack: ``f`` (K, 15, 15), ``x`` (K, 15), one ``dt_s``: each slice's
    own numbers (``np.matmul`` of a stack is each slice's matrix-vector product; tested), in K times
    fewer numpy calls."""
    pieces = max(1, math.ceil(dt_s / TAYLOR_PIECE_S))
    a = f * (dt_s / pieces)
    term = np.empty_like(x)
    term_column = term[..., None]
    for _ in range(pieces):
        y = x.copy()
        for k in range(TAYLOR_TERMS, 0, -1):     # in place: the same operations, no temporaries
            np.matmul(a, y[..., None], out=term_column)
            term *= 1.0 / k
            np.add(x, term, out=y)
        x = y
    return x


def propagate_together(models: Sequence[InsErrorModel], dt_s: Sequence[float], states: Sequence) -> None:
    """:meth:`InsErrorModel.propagate` of several models along their tracks (``states``: each
    vehicle's, with ``lat_deg``, ``vel_east_mps``, ``vel_north_mps``), the exponentials of equal
    steps as one stack (:func:`expm_times_stacked`); each model ends bit for bit where its own
    ``propagate`` would (its random draws stay in its own stream)."""
    groups: dict[float, list[int]] = {}
    for index, dt in enumerate(dt_s):
        if dt > 0.0:
            groups.setdefault(float(dt), []).append(index)
    for dt, members in groups.items():
        f = np.stack([models[i]._dynamics(states[i].lat_deg, states[i].vel_east_mps, states[i].vel_north_mps)
                      for i in members])
        moved = expm_times_stacked(f, dt, np.stack([models[i].state for i in members]))
        for row, i in enumerate(members):
            models[i].state = moved[row]
            models[i]._drive_markov(dt)


EARTH_RATE_RADPS = 7.292115e-5
GRAVITY_MPS2 = 9.7803
ARCMIN = math.radians(1.0 / 60.0)
DEG_PER_HOUR = math.radians(1.0) / 3600.0


@dataclass(frozen=True)
class InsErrorConfig:
    """Initial errors and gyro drift (Table 1). Each initial error is drawn as N(0, value^2)
    per run unless ``deterministic`` is set, in which case it is applied as given."""

    misalign_arcmin: tuple[float, float, float] = (50.0, 50.0, 500.0)
    vel_err_mps: float = 10.0
    pos_err_east_m: float = 5000.0
    pos_err_north_m: float = 5000.0
    gyro_bias_degph: float = 0.01
    gyro_markov_degph: float = 0.005
    gyro_markov_tau_s: float = 3600.0
    deterministic: bool = False
    onboard: bool = True      # False: no navigation-grade INS (ArduPilot, PX4 on MEMS): no INS position

    def __post_init__(self) -> None:
        # 1-sigma values, or with ``deterministic`` the errors themselves (of either sign)
        require(self, ("misalign_arcmin", "vel_err_mps", "pos_err_east_m", "pos_err_north_m", "gyro_bias_degph",
                       "gyro_markov_degph"), lambda v: self.deterministic or v >= 0.0,
                "finite, and a 1-sigma is not negative")
        require(self, ("gyro_markov_tau_s",), lambda v: v > 0.0, "a positive time")


class InsErrorModel:
    """Propagates the INS error along the true track; seeded and reproducible.

    >>> ins = InsErrorModel(InsErrorConfig(deterministic=True), np.random.default_rng(1))
    >>> lat, lon = ins.indicated_position(33.0, 152.0)
    >>> round((lat - 33.0) * 110.9e3)  # the north position error of Table 1, metres
    5000
    """

    def __init__(self, config: InsErrorConfig, rng: np.random.Generator, lat_deg: float = 33.0) -> None:
        self.config = config
        self.rng = rng
        draw = (lambda sigma: sigma) if config.deterministic else (lambda sigma: rng.normal(0.0, sigma))
        m, n = (float(r) for r in radii_of_curvature_m(lat_deg))
        x = np.zeros(15)
        x[0:3] = [draw(a * ARCMIN) for a in config.misalign_arcmin]
        x[3:5] = [draw(config.vel_err_mps / math.sqrt(2.0)) for _ in range(2)]
        x[6] = draw(config.pos_err_north_m) / m
        x[7] = draw(config.pos_err_east_m) / (n * math.cos(math.radians(lat_deg)))
        x[9:12] = [draw(config.gyro_bias_degph * DEG_PER_HOUR) for _ in range(3)]
        x[12:15] = [draw(config.gyro_markov_degph * DEG_PER_HOUR) for _ in range(3)]
        self.state = x
        self._f_constant = self._constant_dynamics()

    def _dynamics(self, lat_deg: float, vel_east_mps: float, vel_north_mps: float) -> np.ndarray:
        lat = math.radians(lat_deg)
        sl, cl = math.sin(lat), math.cos(lat)
        tl = sl / cl
        m, n = radii_of_curvature_m(float(lat_deg))
        ve, vn = vel_east_mps, vel_north_mps
        w_ie_n, w_ie_u = EARTH_RATE_RADPS * cl, EARTH_RATE_RADPS * sl   # Earth rate (0, w cl, w sl)
        w_en_e, w_en_n, w_en_u = -vn / m, ve / n, ve * tl / n          # transport rate
        f = self._f_constant.copy()   # the blocks that do not depend on the track (below)
        # misalignment: phi_dot = -w_in x phi + d(w_in) - eps, w_in = w_ie + w_en; -[w x] entries
        w_in_e, w_in_n, w_in_u = w_en_e, w_ie_n + w_en_n, w_ie_u + w_en_u
        f[0, 1], f[0, 2] = w_in_u, -w_in_n
        f[1, 0], f[1, 2] = -w_in_u, w_in_e
        f[2, 0], f[2, 1] = w_in_n, -w_in_e
        f[0, 4] = -1.0 / m
        f[1, 3] = 1.0 / n
        f[2, 3] = tl / n
        f[1, 6] = -EARTH_RATE_RADPS * sl
        f[2, 6] = EARTH_RATE_RADPS * cl + ve / (n * cl * cl)
        # velocity (horizontal rows): -(2 w_ie + w_en) x dv
        c_e, c_n, c_u = w_en_e, 2.0 * w_ie_n + w_en_n, 2.0 * w_ie_u + w_en_u
        f[3, 4], f[3, 5] = c_u, -c_n
        f[4, 3], f[4, 5] = -c_u, c_e
        # position: lat_dot = dv_n / M, lon_dot = dv_e / (N cos lat) + lon rate change with lat
        f[6, 4] = 1.0 / m
        f[7, 3] = 1.0 / (n * cl)
        f[7, 6] = ve * tl / (n * cl)
        return f

    def _constant_dynamics(self) -> np.ndarray:
        """The part of the error dynamics that is the same at every step: gyro bias and Markov
        drift into the misalignment, the Markov decay, and the specific force (0, 0, g) acting
        on the misalignment in the horizontal velocity channel (the vertical row stays zero:
        the vertical channel is held)."""
        f = np.zeros((15, 15))
        f[0:3, 9:12] = -np.eye(3)
        f[0:3, 12:15] = -np.eye(3)
        # velocity: dv_dot = f_n x phi - (2 w_ie + w_en) x dv (horizontal); f_n = (0, 0, g)
        f[3:5, 0:3] = _skew(np.array([0.0, 0.0, GRAVITY_MPS2]))[0:2]
        f[12:15, 12:15] = -np.eye(3) / self.config.gyro_markov_tau_s
        return f

    def propagate(self, dt_s: float, lat_deg: float, vel_east_mps: float, vel_north_mps: float) -> None:
        """Advance the error by ``dt_s`` along a true track at this latitude and velocity."""
        if dt_s <= 0.0:
            return
        self.state = expm_times(self._dynamics(lat_deg, vel_east_mps, vel_north_mps), dt_s, self.state)
        self._drive_markov(dt_s)

    def _drive_markov(self, dt_s: float) -> None:
        """The random part of a step: the Markov drift's driving noise (after the exponential)."""
        # exact discrete noise of the Markov drift: variance sigma^2 (1 - exp(-2 dt / tau))
        sigma = self.config.gyro_markov_degph * DEG_PER_HOUR
        decay = math.exp(-2.0 * dt_s / self.config.gyro_markov_tau_s)
        if not self.config.deterministic:
            self.state[12:15] += self.rng.normal(0.0, sigma * math.sqrt(max(0.0, 1.0 - decay)), 3)

    def indicated_position(self, true_lat_deg: float, true_lon_deg: float) -> tuple[float, float]:
        """The INS-indicated (lat_deg, lon_deg): truth plus the current position error."""
        return (
            true_lat_deg + math.degrees(self.state[6]),
            (true_lon_deg + math.degrees(self.state[7]) + 180.0) % 360.0 - 180.0,
        )

    def indicated_velocity(self, vel_east_mps: float, vel_north_mps: float) -> tuple[float, float]:
        """The INS-indicated (east, north) velocity in m/s."""
        return vel_east_mps + self.state[3], vel_north_mps + self.state[4]

    def attitude_error_rad(self, yaw_rad: float) -> tuple[float, float, float]:
        """(roll, pitch, yaw) errors of the INS attitude, indicated minus true, in radians.

        The misalignment ``phi`` (ENU) rotates the true navigation frame into the computed one,
        ``C_b^n' = (I - [phi x]) C_b^n``; in NED the error rotation is ``-(phi_n, phi_e, -phi_u)``.
        Its components along the body axes of a level vehicle with this yaw (clockwise from
        north) are the Euler errors: roll ``-(phi_n cos psi + phi_e sin psi)``, pitch
        ``phi_n sin psi - phi_e cos psi``, yaw ``+phi_u`` (the azimuth error psi_z).
        """
        phi_e, phi_n, phi_u = (float(v) for v in self.state[0:3])
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        return -(phi_n * c + phi_e * s), phi_n * s - phi_e * c, phi_u

    def position_error_m(self, lat_deg: float) -> tuple[float, float]:
        """Current (east, north) position error in metres."""
        m, n = (float(r) for r in radii_of_curvature_m(lat_deg))
        return self.state[7] * n * math.cos(math.radians(lat_deg)), self.state[6] * m


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])

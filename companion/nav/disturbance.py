"""The magnetic disturbance the bias states follow: when it is active, and how it moves.

The navigation filter's bias states (:mod:`companion.nav.navfilter`) carry what a measured
element holds beyond the main-field model at the true position. A magnetic storm moves them by
tenths of a degree within hours, far faster than the quiet random walk; this module says when a
disturbance is active and what random walk the bias states then take.

**When** (:class:`DisturbanceMonitor`): either

* the innovations say so: the exponential average (weight ``NIS_ALPHA``) of the normalised
  innovation squared ``NIS / m`` above ``ACTIVE_ON`` for ``ONSET_STEPS`` steps in a row switches
  it on, and ``RELEASE_STEPS`` steps in a row below ``ACTIVE_OFF`` switch it off. ``ACTIVE_ON``
  is set for a false-alarm rate: with innovations exactly as large as the filter says
  (chi-square NIS), 0.4 % of 200-step missions on two elements switch on without a disturbance
  (simulated; 2.3 % at 3.0, 16 % at 2.5, 66 % at 2.0). Once a disturbance has been recognised
  in the mission, switching on again needs only ``REACTIVE_ON``: the test's threshold follows the
  prior odds, and after a storm's onset another loud stretch is far more likely the storm than
  noise;
* or a space-weather index declares it (:meth:`DisturbanceMonitor.declare`): the planetary
  index Kp at or above ``FUS_KP_ON`` (5, a G1 storm on NOAA's scale). The innovations recognise
  a storm only after it has moved the measurement, and what moved before is taken for position
  (short storm, seed 36: 16 km east of the truth within six steps, never recovered); Kp is
  published every three hours (GFZ Potsdam, NOAA SWPC) and reaches a vehicle as a parameter
  (``NAV_KP``) from its ground station. Or the ring-current index SYM-H (``NAV_SYMH``, every
  minute, a 1-min Dst) at or below ``FUS_SYMH_ON`` (-50 nT, a moderate storm): a station may
  relay one without the other (:func:`storm_declared`). While an index declares a storm the
  innovations cannot release it.

**How**: a disturbance only the innovations found is of a nature not known (a storm, or the
main-field model, the crust or a calibration residual failing the model): its bias states walk
per element, ``FUS_BQA_DEG`` on each angle and ``FUS_BQA_NT`` on each intensity, in place of the
quiet walk and scaled by covariance matching (``FUS_BQA_ADAPT`` 1: ``(NIS / m)^ADAPT_GAIN`` of the
averaged NIS a step, between the quiet walk and the declared one; the filter keeps the scale).
A storm a space-weather index declares is known to be a storm, and walks as declared
(``FUS_BQA_MODE``), and with ``FUS_BQA_SADAPT`` 1 (not the default) its rates scaled by covariance
matching too: the same ``(NIS / m)^ADAPT_GAIN`` a step, but never below the declared walk (at most
``STORM_SCALE_MAX`` times it). The declared walks are fitted on other storms (``fcmpc-fit-storms``),
and a storm may walk the field far faster than any of them (Halloween 2003 along its route: 315
nT/rt(h) north, about 50 times the 6.4 it is flown with, fitted on the other three storms): the
innovations then stay larger than the filter predicts (the averaged NIS 5-18 through its main phase,
tuning seed 3) and the filter believes a position the storm has moved. Scaled so, the walk follows
what the innovations show instead of what other storms did; but on a route over land the innovations
are the crust's as much as the storm's, and the larger walk lets the bias states take up what the
crust said of the position (St Patrick's 2015, tuning seeds 0-15: median 7.8 -> 14.4 km), so it is
an option. The declared walk:

* along the field components (1, the default): the disturbance is a vector ``dB = (dN, dE, dZ)``
  (geographic north, east, down, nT) whose components walk at ``q = (FUS_BQA_N, FUS_BQA_E,
  FUS_BQA_Z)`` nT per sqrt(hour), their changes correlated by ``R`` (``FUS_BQA_RNE``, ``_RNZ``,
  ``_REZ``; 0, the default, independent: :class:`StormWalk`); it enters the elements through
  their Jacobian ``J = d(element) / d(N, E, Z)`` at the model's field where the vehicle is
  believed to be (:func:`field_jacobian`), so the bias states walk with
  ``Q = J diag(q) R diag(q) J^T dt`` on top of the quiet walk: correlated between the elements as
  one field vector makes them.
  Why: at low and middle latitudes a storm is mostly the ring current's change of the horizontal
  intensity (the Dst index is that change), which moves I and F together and D hardly at all,
  while D, the east's measure on the Pacific route, moves only with the smaller dE. Per element,
  D's bias walked as fast as I's and the east was lost with it;
  A component may instead be first-order Gauss-Markov with correlation time ``tau``
  (``FUS_BQA_TN``, ``FUS_BQA_TE``, ``FUS_BQA_TZ`` hours; 0, the default, is the random walk):
  ``c' = exp(-dt / tau) c + w``, stationary variance ``q^2 tau / 2``, so it wanders at ``q`` over
  lags short against ``tau`` and stays within ``sqrt(q^2 tau / 2)`` over longer ones. That needs
  memory: each such component is a state of the filter (its column in H is its row of J), which
  starts a declared storm at its stationary variance (the storm is on at the start-up calibration
  too: what the calibration sees of it is not a constant), keeps walking while the storm is
  declared and fades without noise after. A random-walk component needs no state: its walk is
  process noise on the bias states, ``J diag(q^2) J^T dt``. Why a Gauss-Markov component: the
  east component of a storm comes from field-aligned and ionospheric currents that come and go,
  and where it does (the ideal storm worlds, whose rms east change stops growing after 2-4 h), a
  random walk lets D's bias wander without bound and the east with it;
* per element (0) at ``FUS_BQA_DEG``, ``FUS_BQA_NT``, unscaled.

The defaults are how fast the 10 May 2024 storm moved along the Pacific route in real time from
18 UTC over one control step, the filter's noise being per step
(:func:`sitl.world.build.storm_component_walks` on the long storm's window played as it happened:
59.6, 45.6, 30.2 nT per sqrt(hour); over one hour 72, 36, 33), rounded: ``dN`` 60, ``dE`` 46,
``dZ`` 30. A scenario that compresses a storm window onto the mission slows it down, and its
navigator declares its own (README "Storms declared by Kp").
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ACTIVE_OFF",
    "ACTIVE_ON",
    "ADAPT_GAIN",
    "COMPONENT_WALK",
    "ELEMENT_WALK",
    "HOUR_S",
    "NIS_ALPHA",
    "ONSET_STEPS",
    "REACTIVE_ON",
    "RELEASE_STEPS",
    "STORM_SCALE_MAX",
    "BiasWalk",
    "DisturbanceMonitor",
    "StormWalk",
    "component_walk_covariance",
    "field_jacobian",
    "gauss_markov_step",
    "index_says_quiet",
    "stationary_variance",
    "storm_declared",
]

HOUR_S = 3600.0
ELEMENT_WALK = 0     # FUS_BQA_MODE: per element, independent
COMPONENT_WALK = 1   # FUS_BQA_MODE: along the field components, through the elements' Jacobian

NIS_ALPHA = 0.3      # weight of the newest step in the averaged NIS: about 3 steps of memory
ACTIVE_ON = 3.5      # averaged NIS / m above this: a disturbance is active (see the module docstring)
REACTIVE_ON = 2.0    # ... once one has been recognised in this mission: storms last hours, so the
                     # prior odds of one are high, and a late re-detection costs (short storm, seeds 2, 3:
                     # 30 and 36 km re-detecting at 3.5, 26 and 23 km at 2.0)
ONSET_STEPS = 2      # ... for this many steps in a row (one high NIS is noise: with 1, 3 of 8
                     # quiet Pacific missions raised the bias noise and ended 1.8-3.5 km off)
ACTIVE_OFF = 1.2     # ... and below this for RELEASE_STEPS steps in a row it is over
RELEASE_STEPS = 60   # six hours at T = 360 s: a storm lasts hours, and a bias let go too early
                     # is absorbed into the INS error states (measured: long storm 52 km without
                     # the hold, 14 km with it, 4 seeds)
ADAPT_GAIN = 0.5     # covariance matching: the active noise's scale moves by (NIS / m)^ADAPT_GAIN a step
STORM_SCALE_MAX = 100.0   # a declared storm's walk at most this times the declared one (FUS_BQA_SADAPT): a
                          # bound against run-away, not a fit (the library's storms walk 6-315 nT/rt(h) along
                          # their routes; the fitted walks are 3-19, so 100 x leaves every storm inside)


def index_says_quiet(kp: float, kp_on: float, symh_nt: float = math.nan, symh_on_nt: float = -math.inf) -> bool:
    """Whether a space-weather index vouches for a quiet field: at least one of Kp (0-9; NaN or
    negative: unknown) and SYM-H (nT; NaN: unknown) is known, and neither declares a storm.

    >>> index_says_quiet(2.0, 5.0), index_says_quiet(math.nan, 5.0), index_says_quiet(2.0, 5.0, -80.0, -50.0)
    (True, False, False)
    """
    known = (math.isfinite(kp) and kp >= 0.0) or math.isfinite(symh_nt)
    return known and not storm_declared(kp, kp_on, symh_nt, symh_on_nt)


def storm_declared(kp: float, kp_on: float, symh_nt: float = math.nan, symh_on_nt: float = -math.inf) -> bool:
    """Whether a space-weather index declares a storm: the planetary Kp (0-9; NaN or negative:
    unknown) at or above ``kp_on``, or the ring-current index SYM-H (nT; NaN: unknown) at or
    below ``symh_on_nt``.

    >>> storm_declared(6.0, 5.0), storm_declared(math.nan, 5.0, -80.0, -50.0), storm_declared(2.0, 5.0, -20.0, -50.0)
    (True, True, False)
    """
    return (math.isfinite(kp) and kp >= 0.0 and kp >= kp_on) or (math.isfinite(symh_nt) and symh_nt <= symh_on_nt)


class DisturbanceMonitor:
    """Averaged normalised innovation squared, and whether a disturbance is active (by the
    innovations or declared by a space-weather index)."""

    def __init__(self) -> None:
        self.average = 1.0
        self.active = False
        self.declared = False
        self.index_quiet = False    # a fresh space-weather index says the field is quiet
        self.quiet_steps = 0
        self.loud_steps = 0
        self.activations = 0
        self.storm_nis = (0.0, 0)   # sum of NIS / m and updates while an index declared a storm

    def variance_factor(self) -> float:
        """The a-posteriori variance factor of the declared storm's updates, ``mean(NIS / m)``,
        at least 1 (FUS_BQA_SADAPT 3 scales the reported position covariance by it)."""
        total, count = self.storm_nis
        return max(1.0, total / count) if count else 1.0

    def declare(self, storm: bool, index_quiet: bool = False) -> bool:
        """A space-weather index says whether a storm is on (``storm``) or the field is quiet
        (``index_quiet``; both False: no index); returns whether active. A declared storm switches
        the disturbance on at once; its end leaves the release to the innovations."""
        self.declared = bool(storm)
        self.index_quiet = bool(index_quiet) and not self.declared
        if self.declared and not self.active:
            self.active = True
            self.activations += 1
        return self.active

    def observe(self, whitened: np.ndarray) -> bool:
        """One update's whitened innovation ``L^-1 y`` (``S = L L^T``); returns whether active."""
        w = np.asarray(whitened, dtype=float)
        nis_m = float(w @ w) / len(w)
        self.average = (1.0 - NIS_ALPHA) * self.average + NIS_ALPHA * nis_m
        if self.declared:
            self.storm_nis = (self.storm_nis[0] + nis_m, self.storm_nis[1] + 1)
        self.quiet_steps = self.quiet_steps + 1 if self.average < ACTIVE_OFF else 0
        threshold = ACTIVE_ON if self.activations == 0 else REACTIVE_ON
        self.loud_steps = self.loud_steps + 1 if self.average > threshold else 0
        if self.active and not self.declared and self.quiet_steps >= RELEASE_STEPS:
            self.active = False
        elif not self.active and self.loud_steps >= ONSET_STEPS:
            self.active = True
            self.activations += 1
        return self.active

    def snapshot(self) -> tuple:
        return (self.average, self.active, self.declared, self.index_quiet, self.quiet_steps, self.loud_steps,
                self.activations, self.storm_nis)

    def restore(self, state: tuple) -> None:
        (self.average, self.active, self.declared, self.index_quiet, self.quiet_steps, self.loud_steps,
         self.activations, self.storm_nis) = state


def field_jacobian(names: tuple[str, ...], north_nt: float, east_nt: float, down_nt: float) -> np.ndarray:
    """``d(element) / d(N, E, Z)`` of each named element (``decl_deg``, ``incl_deg``, ``f_nt``,
    ``h_nt``, ``z_nt``) at the field ``(N, E, Z)`` nT: one row per element, in degrees per nT
    for the angles and nT per nT for the intensities.

    ``D = atan2(E, N)``, ``I = atan2(Z, H)``, ``H = sqrt(N^2 + E^2)``, ``F = sqrt(H^2 + Z^2)``.

    >>> field_jacobian(("f_nt", "z_nt"), 30000.0, 0.0, 40000.0).round(3).tolist()
    [[0.6, 0.0, 0.8], [0.0, 0.0, 1.0]]
    """
    n, e, z = float(north_nt), float(east_nt), float(down_nt)
    h2 = n * n + e * e
    h = math.sqrt(h2)
    f2 = h2 + z * z
    f = math.sqrt(f2)
    if not (h > 0.0 and math.isfinite(f)):
        raise ValueError(f"field_jacobian: no horizontal field at N {n} E {e} Z {z} nT")
    rad = math.degrees(1.0)
    rows = {
        "decl_deg": (-e / h2 * rad, n / h2 * rad, 0.0),
        "incl_deg": (-z * n / (h * f2) * rad, -z * e / (h * f2) * rad, h / f2 * rad),
        "f_nt": (n / f, e / f, z / f),
        "h_nt": (n / h, e / h, 0.0),
        "z_nt": (0.0, 0.0, 1.0),
    }
    return np.array([rows[name] for name in names])


def component_walk_covariance(jacobian: np.ndarray, q_ned_nt_rth: np.ndarray, dt_s: float) -> np.ndarray:
    """Covariance (element units squared) over ``dt_s`` of the elements' bias walk driven by the
    field components walking at ``q_ned_nt_rth`` (N, E, Z; nT per sqrt(hour)):
    ``J diag(q^2) J^T dt / 1 h``."""
    scaled = jacobian * np.asarray(q_ned_nt_rth, dtype=float)
    return scaled @ scaled.T * (dt_s / HOUR_S)


def gauss_markov_step(q_rth: np.ndarray, tau_s: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of first-order Gauss-Markov processes that wander at ``q_rth`` per sqrt(hour) over
    short lags, with correlation times ``tau_s``: the decay ``exp(-dt / tau)`` and the driving
    noise's variance ``q^2 tau / 2 (1 - decay^2)`` (its stationary variance is ``q^2 tau / 2``)."""
    tau = np.asarray(tau_s, dtype=float)
    decay = np.exp(-dt_s / tau)
    return decay, stationary_variance(q_rth, tau) * (1.0 - decay * decay)


def stationary_variance(q_rth: np.ndarray, tau_s: np.ndarray) -> np.ndarray:
    """``q^2 tau / 2``: the variance a Gauss-Markov process of short-lag rate ``q_rth`` (per
    sqrt(hour)) and correlation time ``tau_s`` settles at (units of q squared)."""
    return np.asarray(q_rth, dtype=float) ** 2 * (np.asarray(tau_s, dtype=float) / HOUR_S) / 2.0


@dataclass(frozen=True)
class StormWalk:
    """How a declared storm's field components walk: short-lag rate ``q_rth`` (N, E, Z; nT per
    sqrt(hour)), correlation time ``tau_h`` (hours; 0: a random walk, no state needed) and the
    correlation ``corr`` of the components' changes over a step (N-E, N-Z, E-Z): a storm's
    currents move them together (10 May 2024 along the Pacific route, over 6 min: N-Z +0.7, E-Z
    -0.8 once the ring current is removed), so independent walks would overstate some
    combinations of the elements and understate others. Three values that no correlation matrix
    has (not positive semi-definite) are taken at the nearest one that is."""

    q_rth: tuple[float, float, float]
    tau_h: tuple[float, float, float] = (0.0, 0.0, 0.0)
    corr: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @functools.cached_property
    def correlation(self) -> np.ndarray:
        """The 3 x 3 correlation matrix of the components' changes (positive semi-definite;
        computed once: the filter asks for it at every step of a declared storm)."""
        ne, nz, ez = self.corr
        r = np.array([[1.0, ne, nz], [ne, 1.0, ez], [nz, ez, 1.0]])
        values, vectors = np.linalg.eigh(r)
        if values[0] >= 0.0:
            return r
        r = (vectors * np.maximum(values, 0.0)) @ vectors.T   # clip, then back to a unit diagonal
        scale = np.sqrt(np.diag(r))
        return r / np.outer(scale, scale)

    @functools.lru_cache(maxsize=4)   # noqa: B019 - a frozen value: the bias noise, the cross terms
    def increment_covariance(self, dt_s: float) -> np.ndarray:   # and the states' noise ask each step
        """Covariance (nT^2) of the components' changes over ``dt_s``: a random walk's ``q^2 dt``,
        a Gauss-Markov component's driving noise (:func:`gauss_markov_step`), correlated by
        :attr:`correlation`. Read-only: computed once per step length."""
        covariance = self._increment_covariance(dt_s)
        covariance.setflags(write=False)
        return covariance

    def _increment_covariance(self, dt_s: float) -> np.ndarray:
        q, tau = np.asarray(self.q_rth, dtype=float), np.asarray(self.tau_h, dtype=float) * HOUR_S
        variance = q ** 2 * dt_s / HOUR_S
        markov = tau > 0.0
        if np.any(markov):
            variance[markov] = gauss_markov_step(q[markov], tau[markov], dt_s)[1]
        if not any(self.corr):
            return np.diag(variance)
        sigma = np.sqrt(variance)
        return self.correlation * np.outer(sigma, sigma)

    @property
    def states(self) -> np.ndarray:
        """The components that are Gauss-Markov, each a state of the filter (indices into N, E, Z)."""
        return np.flatnonzero(np.asarray(self.tau_h) > 0.0)

    @property
    def walks(self) -> np.ndarray:
        """The random-walk components, process noise on the bias states."""
        return np.flatnonzero(np.asarray(self.tau_h) <= 0.0)

    def bias_noise(self, jacobian: np.ndarray, dt_s: float) -> np.ndarray:
        """The random-walk components' covariance on the bias states over ``dt_s``:
        ``J_w C_ww J_w^T`` (``C``: :meth:`increment_covariance`)."""
        walks = self.walks
        if not any(self.corr):   # independent: the same numbers as before the correlations
            return component_walk_covariance(jacobian[:, walks], np.asarray(self.q_rth)[walks], dt_s)
        j = jacobian[:, walks]
        return j @ self.increment_covariance(dt_s)[np.ix_(walks, walks)] @ j.T

    def cross_noise(self, jacobian: np.ndarray, dt_s: float) -> np.ndarray:
        """Covariance over ``dt_s`` between the bias states' walk and the Gauss-Markov states'
        driving noise (bias rows, state columns): ``J_w C_ws``; zero for independent components."""
        walks, states = self.walks, self.states
        return jacobian[:, walks] @ self.increment_covariance(dt_s)[np.ix_(walks, states)]

    def _gauss_markov(self) -> tuple[np.ndarray, np.ndarray]:
        """The Gauss-Markov components' short-lag rates (nT per sqrt(hour)) and correlation times (s)."""
        states = self.states
        return np.asarray(self.q_rth)[states], np.asarray(self.tau_h)[states] * HOUR_S

    def state_step(self, dt_s: float, declared: bool) -> tuple[np.ndarray, np.ndarray]:
        """Decay and driving-noise covariance (a matrix over the states) of the Gauss-Markov states
        over ``dt_s``: driven while the storm is declared, fading without noise after."""
        decay = gauss_markov_step(*self._gauss_markov(), dt_s)[0]
        states = self.states
        if not declared:
            return decay, np.zeros((len(states), len(states)))
        return decay, self.increment_covariance(dt_s)[np.ix_(states, states)]

    def initial_variance(self) -> np.ndarray:
        """The Gauss-Markov states' stationary variance, where a declared storm starts them (nT^2)."""
        return stationary_variance(*self._gauss_markov())


class BiasWalk:
    """The bias states' walk over one step (element units squared, one row per element of
    ``names``): the quiet walk ``quiet_rth`` per sqrt(hour) and ``distance_rkm`` per sqrt(km), and
    while a disturbance is active the active walk. A storm a space-weather index declares walks as
    declared: along the field components (``storm`` given: its random-walk components here, its
    Gauss-Markov ones as filter states) on top of the quiet walk, or per element at
    ``active_rth``; a disturbance only the innovations found, of a nature not known, walks per
    element at ``active_rth`` times the covariance-matching scale, in place of the quiet walk.
    ``field_ned(lat, lon)``: the model's (N, E, Z) in nT, for the elements' Jacobian where the
    vehicle is believed to be (:attr:`position`)."""

    def __init__(self, names: tuple[str, ...], quiet_rth: np.ndarray, distance_rkm: np.ndarray,
                 active_rth: np.ndarray, storm: StormWalk | None,
                 field_ned: Callable[[float, float], tuple[float, float, float]]) -> None:
        self.names = names
        self.quiet_rth, self.distance_rkm, self.active_rth = quiet_rth, distance_rkm, active_rth
        self.storm = storm
        self.field_ned = field_ned
        self.position: tuple[float, float] | None = None
        # covariance matching goes down to the quiet walk, never below
        self.scale_floor = float(np.max(quiet_rth / np.maximum(active_rth, 1e-300)))

    @property
    def states(self) -> np.ndarray:
        """The storm's Gauss-Markov components, each a filter state (indices into N, E, Z)."""
        return self.storm.states if self.storm is not None else np.zeros(0, dtype=int)

    def along_components(self, monitor: DisturbanceMonitor) -> bool:
        """A declared storm walks along the field components."""
        return monitor.declared and self.storm is not None

    def jacobian(self) -> np.ndarray:
        """The elements' ``d / d(N, E, Z)`` at the model's field at :attr:`position`."""
        if self.position is None:
            raise ValueError("the active walk along the field components needs a position: "
                             "predict(..., position_deg=(lat, lon)) or calibrate first")
        return field_jacobian(self.names, *self.field_ned(*self.position))

    def noise(self, dt_s: float, distance_km: float, monitor: DisturbanceMonitor, scale: float,
              jacobian: np.ndarray | None = None, storm_scale: float = 1.0) -> np.ndarray:
        """The covariance of one step; ``jacobian`` (:meth:`jacobian`) for a walk along the
        components, ``scale`` the covariance-matching scale of an innovation-found disturbance,
        ``storm_scale`` that of a declared storm (:meth:`storm_matched`)."""
        quiet = self.quiet_rth ** 2 * dt_s / HOUR_S + self.distance_rkm ** 2 * distance_km
        if not monitor.active:
            return np.diag(quiet)
        if self.along_components(monitor):
            walk = self.storm.bias_noise(jacobian if jacobian is not None else self.jacobian(), dt_s)
            return np.diag(quiet) + walk * storm_scale ** 2
        q = self.active_rth * (storm_scale if monitor.declared else scale)
        return np.diag(q ** 2 * dt_s / HOUR_S + self.distance_rkm ** 2 * distance_km)

    def matched_scale(self, scale: float, monitor: DisturbanceMonitor, was_active: bool) -> float:
        """Covariance matching of an active walk: a disturbance starts at the declared walk; then
        each step its scale moves by ``(NIS / m)^ADAPT_GAIN`` of the monitor's averaged NIS, so
        innovations larger than the filter predicts raise it and smaller ones (a walk so loose
        that the bias absorbs every measurement) lower it, between the quiet walk and the
        declared one."""
        if not was_active:
            return 1.0
        return min(1.0, max(self.scale_floor, scale * monitor.average ** ADAPT_GAIN))

    def storm_states_noise(self, dt_s: float, declared: bool, jacobian: np.ndarray | None,
                           storm_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray | float]:
        """The storm's Gauss-Markov states over ``dt_s``: their decay, their driving noise
        (:meth:`StormWalk.state_step`: driven while declared, fading after) and its covariance with
        the bias states' walk (:meth:`StormWalk.cross_noise`: driven together while declared, 0
        after), the noise at ``storm_scale`` squared (:meth:`storm_matched`)."""
        decay, driven = self.storm.state_step(dt_s, declared)
        cross = self.storm.cross_noise(jacobian, dt_s) if declared else 0.0
        return decay, driven * storm_scale ** 2, cross * storm_scale ** 2

    @staticmethod
    def storm_matched(scale: float, monitor: DisturbanceMonitor, adapt: int = 1) -> float:
        """Covariance matching of a declared storm's walk: while an index declares the storm, its
        scale moves each step by ``(NIS / m)^ADAPT_GAIN`` of the monitor's averaged NIS, between
        the declared walk (1: the fitted walks are a floor, innovations smaller than predicted
        do not take them away) and ``STORM_SCALE_MAX``; 1 again once no index declares one.

        >>> m = DisturbanceMonitor(); m.declared, m.average = True, 9.0
        >>> BiasWalk.storm_matched(1.0, m), BiasWalk.storm_matched(2.0, m)
        (3.0, 6.0)
        >>> m.average = 0.25; BiasWalk.storm_matched(6.0, m), BiasWalk.storm_matched(1.5, m)
        (3.0, 1.0)
        >>> m.average = 2.25; BiasWalk.storm_matched(2.0, m, 2), BiasWalk.storm_matched(2.0, m, 1)   # 2: held
        (2.0, 3.0)
        """
        if not (monitor.declared and adapt in (1, 2)):
            return 1.0
        if adapt == 2 and 1.0 <= monitor.average <= ACTIVE_ON:   # 2: raised only beyond the onset threshold
            return scale
        return min(STORM_SCALE_MAX, max(1.0, scale * monitor.average ** ADAPT_GAIN))

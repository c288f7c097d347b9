"""The error-state filter's settings (:mod:`companion.nav.navfilter`), built from the registry:
the declared and measured element noise, the bias states and how they walk, the INS the filter
assumes and the dead reckoning's uncertainty. Every value is a ``FUS_*`` entry of
:mod:`companion.registry`; the classes hold no defaults of their own."""
from __future__ import annotations

from dataclasses import field, replace

import numpy as np

from companion.nav.disturbance import StormWalk
from companion.nav.ins_error import InsErrorSpec
from companion.nav.process import DeadReckoningSpec
from companion.registry import settings

__all__ = ["BiasSpec", "FilterSettings"]


@settings("bias")
class BiasSpec:
    """Bias states: prior 1-sigma, and random walk per sqrt(hour) while quiet and while a
    disturbance is active, for angles (deg) and intensities (nT), plus a random walk per
    sqrt(km) travelled (``qd_*_rkm``: the main-field model's error relative to the start-up
    calibration, which holds at the start and less the farther the vehicle goes); and the local model error:
    a Gauss-Markov process in distance travelled of stationary 1-sigma ``local_deg`` /
    ``local_nt``, correlation length ``local_length_m`` and order ``local_order`` (1 rough, 2 smooth:
    :mod:`companion.nav.local_error`; no such states when both sigmas are 0), the sigmas holding
    at a route's crustal strength ``local_crust_nt`` (:meth:`with_local_scale`,
    :mod:`companion.nav.crust`); and
    the calibration residual's dependence on the heading: prior 1-sigma ``heading_deg`` /
    ``heading_nt`` of each coefficient of its first and second harmonics (no such states when
    the measured elements' own one is 0: (D, I) has none with ``heading_deg`` 0). While a
    disturbance is active the biases walk per element at ``qa_*_rth`` (``qa_mode`` 0) or along
    the field components at ``qa_ned_nt_rth`` (N, E, Z, nT per sqrt(hour); ``qa_mode`` 1), each a
    random walk or, with a correlation time ``qa_ned_tau_h`` (hours), Gauss-Markov, their changes
    correlated by ``qa_ned_corr`` (N-E, N-Z, E-Z); see :mod:`companion.nav.disturbance`. With the
    ring current removed by SYM-H the north component walks at ``symh_n_nt_rth`` instead
    (:meth:`after_ring_current`). Every field is a registry entry (``FUS_B*``, ``FUS_GM_*``,
    ``FUS_SYMH_N*``/``R*``)."""

    sigma0_deg: float
    sigma0_nt: float
    q_deg_rth: float
    q_nt_rth: float
    qa_deg_rth: float
    qa_nt_rth: float
    local_deg: float
    local_nt: float
    local_length_m: float
    local_order: int
    local_crust_nt: float
    qd_deg_rkm: float
    qd_nt_rkm: float
    qa_adapt: int
    storm_adapt: int
    heading_deg: float
    heading_nt: float
    qa_mode: int
    qa_n_nt_rth: float
    qa_e_nt_rth: float
    qa_z_nt_rth: float
    qa_tn_h: float
    qa_te_h: float
    qa_tz_h: float
    qa_rne: float
    qa_rnz: float
    qa_rez: float
    symh_n_nt_rth: float
    symh_tn_h: float
    symh_rne: float
    symh_rnz: float

    @property
    def qa_ned_nt_rth(self) -> tuple[float, float, float]:
        return self.qa_n_nt_rth, self.qa_e_nt_rth, self.qa_z_nt_rth

    @property
    def qa_ned_tau_h(self) -> tuple[float, float, float]:
        return self.qa_tn_h, self.qa_te_h, self.qa_tz_h

    @property
    def qa_ned_corr(self) -> tuple[float, float, float]:
        return self.qa_rne, self.qa_rnz, self.qa_rez

    def after_ring_current(self) -> BiasSpec:
        """These settings once the ring current predicted from SYM-H is taken out of every
        measurement: what the prediction misses walks as the storm's north component."""
        return replace(self, qa_n_nt_rth=self.symh_n_nt_rth, qa_tn_h=self.symh_tn_h, qa_rne=self.symh_rne,
                       qa_rnz=self.symh_rnz)

    @property
    def storm_walk(self) -> StormWalk:
        """How a declared storm walks along the field components (``qa_mode`` 1)."""
        return StormWalk(self.qa_ned_nt_rth, self.qa_ned_tau_h, self.qa_ned_corr)

    def with_local_scale(self, scale: float) -> BiasSpec:
        """These settings with what the map misses along the route times ``scale`` (the route's
        crust, :func:`companion.nav.crust.local_error_scale`): the local model-error sigmas and
        the per-distance walk of the biases."""
        return replace(self, local_deg=self.local_deg * scale, local_nt=self.local_nt * scale,
                       qd_deg_rkm=self.qd_deg_rkm * scale, qd_nt_rkm=self.qd_nt_rkm * scale)

    @property
    def has_local(self) -> bool:
        return self.local_deg > 0.0 or self.local_nt > 0.0

    @staticmethod
    def per_element(names: tuple[str, ...], deg: float, nt: float) -> np.ndarray:
        return np.array([nt if name.endswith("_nt") else deg for name in names])


@settings("filter")
class FilterSettings:
    """Declared measurement noise of an averaged element (1-sigma, deg or nT: ``FUS_R_*``), whether
    the measured standard errors are used instead (``r_source`` 1, floored by ``r_min_*`` in
    quadrature), which part of the attitude is the INS's (:class:`AttitudeSource`), the bias
    states, the INS the navigator assumes, and the dead-reckoning uncertainty."""

    r_deg: float
    r_nt: float
    r_source: int
    r_min_deg: float
    r_min_nt: float
    attitude_from_ins: int
    bias: BiasSpec = field(default_factory=BiasSpec)
    ins: InsErrorSpec = field(default_factory=InsErrorSpec)
    dead_reckoning: DeadReckoningSpec = field(default_factory=DeadReckoningSpec)

"""What the navigation core is told: the mission's settings, built from the parameter registry.

Every field is a registry entry (``to="nav.<field>"`` in :mod:`companion.registry`, with its
unit conversion there: ``NAV_SPEED_KMH`` becomes ``speed_mps``), or a nested settings group
(``filter``: the error-state filter's, ``fusion``: Table 3's, ``model_error``: the field
model's error); the classes hold no defaults of their own (:func:`companion.registry.settings`).
The space-weather readings are not settings: they come with each step's measurement.

>>> cfg = NavConfig.from_values({"NAV_SPEED_KMH": 72.0, "FUS_BQ_DEG": 0.003})
>>> round(cfg.speed_mps, 9), cfg.filter.bias.q_deg_rth, cfg.horizon
(20.0, 0.003, 2)
"""
from __future__ import annotations

from dataclasses import field, replace

from companion.nav.fusion import FusionSettings, ModelError
from companion.nav.filter_settings import FilterSettings
from companion.registry import settings

__all__ = ["Controller", "NavConfig"]


class Controller:
    """Values of NAV_CONTROLLER."""

    LTI = 0
    LTV = 1
    FC = 2
    NAMES = {0: "LTI-MPC", 1: "LTV-MPC", 2: "Fc-MPC"}


@settings("nav")
class NavConfig:
    """What the pure navigation core needs: mission, gradient, MPC and estimator settings (SI)."""

    start_lat_deg: float
    start_lon_deg: float
    dest_lat_deg: float
    dest_lon_deg: float
    alt_m: float
    year: float
    wmm: int
    nav_map: int
    speed_mps: float
    period_s: float
    arrive_m: float
    arrive_legs: int
    final_leg: int
    lookahead_m: float
    max_steps: int
    probe1_deg: float
    probe2_deg: float
    controller: int
    speed_mode: int
    grad_update: int
    grad_min_move_m: float
    horizon: int
    q_d: float
    q_i: float
    f_d: float
    f_i: float
    r_x: float
    r_y: float
    mpc_units: int
    u_bounds: int
    u_max_mps: float
    s_min_d: float
    s_min_i: float
    s_max_d: float
    s_max_i: float
    s_min_f: float
    s_max_f: float
    s_auto: int
    s_margin_deg: float
    s_admit: int
    elements: int
    calibrate: int
    fix_gate_m: float
    reanchor_steps: int
    dr_heading: int
    solver: int
    fusion_sigma_deg_per_m: float
    fusion_model: int
    kp_on: float
    symh_on_nt: float
    symh_ratio: float
    gps_sigma_m: float
    grad_init: int
    filter: FilterSettings = field(default_factory=FilterSettings)
    fusion: FusionSettings = field(default_factory=FusionSettings)
    model_error: ModelError = field(default_factory=ModelError)

    def replace(self, **changes) -> NavConfig:
        """A copy with some fields changed (for scripts and tests)."""
        return replace(self, **changes)

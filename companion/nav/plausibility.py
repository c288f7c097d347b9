"""Magnetometer plausibility (issue 10, item 6): is this period's measurement one to navigate on?

Judged before the core sees the measurement, against where the vehicle should be: the last
estimate flown on with the last command (:meth:`CurrentEstimate.position <companion.process.estimate.CurrentEstimate.position>`), uncertainty
``sigma_m`` (the estimate's 1-sigma against this fix: ``Command.next_fix_sigma_m`` where the
navigator gives one, Table 3's path, whose own 1-sigma holds the field model's error that the
next fix shares; else ``est_sigma_m``). Two checks:

``f_band``    ``|F_measured - bias_F - F_model(predicted) - F_reference|`` over ``f_band_nt``
              (1000 nT: the model's own error at sea is ~100 nT, the crustal field a few hundred).
              ``F_reference`` is the same difference at the mission's first step (the start, a
              known position): a magnetometer's scale residual or a simulator's coarser field
              (PX4 SIH's |F| sat 7000-8000 nT below WMM's) is a constant level the vehicle could
              never navigate out of, so the band judges a change of |F|, not its level. A
              body-frame offset of 3000 nT, a 20000 nT spike appearing in flight fail here.
``fix_jump``  the position the measurement implies, linearised about the prediction
              (``d = G^-1 (S_measured - bias - S_model(predicted))``, G the element gradient per
              metre), further than ``3 sigma + 3 sigma_noise + slack x speed x dt + margin_m``
              from the prediction. Measured on the clean lockstep Pacific mission: at most 2.2 km
              (median 0.6 km); the bound there is ~27 km. Skipped where G is ill-conditioned (the
              fix is weak anyway and the core does not steer on it, FUS_SIGMA).
              ``sigma_noise`` is the measurement's own noise as a distance: the standard errors of
              the period's averaged elements (:func:`element_noise`, from the period's own scatter,
              :mod:`companion.nav.inclination`) through ``G^-1``, ``sqrt(trace(G^-1 R G^-T))``. A
              magnetometer that is noisy but unbiased (PX4 SIH: 2000-3000 nT per sample and a
              shaking accelerometer, I_g good to 0.21-0.29 deg over a 160 s period: 130-210 km)
              widens the bound by what its fix can scatter; a spike's few samples do not (the
              errors are robust, MAD-based) and a sustained offset adds no scatter at all. The
              lockstep Pacific mission (150 nT at 10 Hz over 360 s): 2.0-2.4 km.
              With the error-state filter, ``bias`` in ``d`` is the filter's bias states (the
              calibration, the model's error, a storm it has recognised; ``fix_bias``) and their
              1-sigma joins the noise: the fix is judged as the filter will see it. Judged
              against the start-up calibration alone, a storm the filter was tracking grew the
              implied jump past the bound and every later step was excluded (short storm, seed 0:
              64 km short after 30 simulated hours).

An implausible measurement is excluded: the step is postponed one period and the vehicle flies
its last command (the core's dead reckoning uses the actual time between steps). Each exclusion
says which check failed (STATUSTEXT); ``sustained_steps`` in a row are flagged as a sustained
offset (CRITICAL); the first plausible one after says so. The core's own 50 km fix gate
(NAV_FIX_GATE_M) stays as the last line.

Both checks take the prediction as the truth, so a wrong estimate would make every later good
fix a "jump" and the vehicle would fly its last course on for good (ArduPilot SITL, full
Pacific run: 40 periods excluded, 333 km to go after 26 h). When ``NAV_REANCHOR_N`` fix_jump
exclusions in a row imply the same offset from the prediction (within the agreement tolerance,
widened by the fixes' own noise and the dead reckoning's slack over a period), the estimate is
what is wrong: the measurement is taken and the core re-anchors there
(:class:`companion.nav.reanchor.OffsetConsensus`, :meth:`Mission.reanchor`), so the vehicle
flies on its last course for at most that many periods.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from companion.nav.elements import ElementSet
from companion.nav.field import WorldMagneticModel, element_values_and_gradient
from companion.nav.reanchor import OffsetConsensus, ReanchorSettings
from companion.nav.small import inverse2, smallest_singular_value

__all__ = ["Judgement", "MagPlausibility", "PlausibilityLimits", "element_noise", "f_offset_nt", "judge",
           "navigator_bias"]

MIN_GRADIENT_SV = 1e-9    # deg (or nT-scaled) per metre: below, the linearised fix is not judged


@dataclass(frozen=True)
class PlausibilityLimits:
    f_band_nt: float = 1000.0
    sigma_k: float = 3.0
    speed_slack: float = 0.5          # fraction of the distance flown since the last step (currents, speed error)
    margin_m: float = 20_000.0        # model error, storms, the first steps' uncalibrated bias (core gate: 50 km)
    sustained_steps: int = 2


@dataclass(frozen=True)
class Judgement:
    ok: bool
    kind: str = ""                    # "f_band" or "fix_jump"
    f_offset_nt: float = math.nan
    jump_m: float = math.nan
    bound_m: float = math.nan
    noise_m: float = 0.0              # the bound's term for the measurement's own noise (3 sigma_noise)
    offset_en_m: tuple[float, float] = (math.nan, math.nan)   # the implied fix minus the prediction, east/north
    pred_lat_deg: float = math.nan    # the prediction judged against (degrees) and its 1-sigma (m)
    pred_lon_deg: float = math.nan
    sigma_m: float = math.nan

    def words(self) -> str:
        if self.kind == "f_band":
            return f"|F| {self.f_offset_nt:+.0f} nT off the model"
        if self.kind == "fix_jump":
            return (f"fix would jump {self.jump_m / 1000.0:.1f} km (bound {self.bound_m / 1000.0:.1f} km, "
                    f"noise {self.noise_m / 1000.0:.1f} km)")
        return "plausible"


def f_offset_nt(model: WorldMagneticModel, elements: ElementSet, year: float, alt_m: float, f_nt: float,
                bias: np.ndarray, lat_deg: float, lon_deg: float, model_f_nt: float | None = None) -> float:
    """``F_measured - bias_F - F_model(lat, lon)``, nT (``bias_F`` 0 when the set has no F);
    ``model_f_nt``: the model's F there, when the caller has it already."""
    f_bias = bias[list(elements.names).index("f_nt")] if "f_nt" in elements.names else 0.0
    if model_f_nt is None:
        model_f_nt = float(model.elements(lat_deg, lon_deg, alt_m, year).f_nt)
    return float(f_nt - f_bias - model_f_nt)


def navigator_bias(mission, heading_rad: float = math.nan) -> tuple[np.ndarray, np.ndarray]:
    """What a steering-pair measurement carries besides the field for ``mission`` (a
    :class:`companion.nav.mission.Mission`), in element units: the bias its navigator removes before
    the fix, and that bias's 1-sigma. Table 3's path: the start-up calibration, taken as exact. The
    error-state filter: its bias states (the calibration, the model's error, a storm it has
    recognised) and their uncertainty, as of its last update, with its heading states (the
    magnetometer's calibration residual, which turns with the vehicle) taken at ``heading_rad``, the
    true heading of the window judged, as the filter's step will take them (NaN: not known); before
    its first step, nothing known (zero bias, its prior 1-sigma). Taken at the last window's heading
    instead, a turn made the residual's change a "jump": the realistic Pacific, closed loop, had every
    period after take-off excluded (fix would jump 146-349 km against a 59-81 km bound)."""
    n = len(mission.elements.names)
    estimator = getattr(mission, "estimator", None)
    f = estimator.filter if estimator is not None else None
    if f is not None:
        f.set_heading(heading_rad)
        return f.bias[:n], f.bias_sigma[:n]
    if estimator is not None:
        s = estimator.settings.bias
        return np.zeros(n), s.per_element(mission.elements.names, s.sigma0_deg, s.sigma0_nt)
    return np.asarray(mission.bias[:n], dtype=float), np.zeros(n)


def element_noise(elements: ElementSet, incl_deg: float, f_nt: float, se: dict[str, float]) -> np.ndarray:
    """1-sigma noise of the set's averaged elements from the standard errors ``se`` of the averages
    (``decl_deg``, ``incl_deg``, ``f_nt``); H and Z (``F cos I``, ``F sin I``) from those of F and I.
    A missing or non-finite error is 0 (nothing known: no widening).

    >>> from companion.nav.elements import ELEMENT_SETS
    >>> element_noise(ELEMENT_SETS[ElementSet.HORIZONTAL_VERTICAL], 0.0, 50000.0,
    ...               {"incl_deg": math.degrees(0.001), "f_nt": 30.0}).round(6).tolist()
    [30.0, 50.0]
    """
    def known(name: str) -> float:
        value = se.get(name, math.nan)
        return value if math.isfinite(value) else 0.0
    s_i, s_f = math.radians(known("incl_deg")), known("f_nt")
    c, s = math.cos(math.radians(incl_deg)), math.sin(math.radians(incl_deg))
    derived = {"h_nt": math.hypot(c * s_f, f_nt * s * s_i), "z_nt": math.hypot(s * s_f, f_nt * c * s_i)}
    values = [derived[n] if n in derived else known(n) for n in elements.names]
    return np.array([v if math.isfinite(v) else 0.0 for v in values])


def judge(model: WorldMagneticModel, elements: ElementSet, year: float, alt_m: float, measured: np.ndarray,
          f_nt: float, bias: np.ndarray, pred_lat_deg: float, pred_lon_deg: float, sigma_m: float,
          flown_m: float, limits: PlausibilityLimits = PlausibilityLimits(),
          f_reference_nt: float = 0.0, noise: np.ndarray | None = None,
          fix_bias: np.ndarray | None = None) -> Judgement:
    """Judge one averaged measurement (``measured``: the element set's two values, bias not yet
    removed; ``bias``: the start-up calibration of those two) against the predicted position;
    ``f_reference_nt``: :func:`f_offset_nt` at the mission's first step; ``noise``: the 1-sigma
    noise of the two measured values (:func:`element_noise`; None: none); ``fix_bias``: the bias
    the navigator removes before its fix, if not ``bias`` (the error-state filter's bias states).
    The |F| band keeps ``bias``: it judges the sensor against its own start, so an offset the
    navigator's bias states have absorbed is still caught there.

    >>> from companion.nav.elements import ELEMENT_SETS
    >>> from companion.nav.field import model_for_date
    >>> m, e = model_for_date(2020.5), ELEMENT_SETS[ElementSet.HEADING_FREE]
    >>> here = m.elements(30.0, 155.0, 0.0, 2020.5)
    >>> judge(m, e, 2020.5, 0.0, e.values(here), float(here.f_nt), np.zeros(2), 30.0, 155.0, 800.0, 5000.0).ok
    True
    >>> judge(m, e, 2020.5, 0.0, e.values(here), float(here.f_nt) + 3000.0, np.zeros(2), 30.0, 155.0,
    ...       800.0, 5000.0).kind
    'f_band'
    """
    # the model there, its elements and their gradient from one evaluation of the harmonic sums (the
    # model keeps its last answers, so asking again for its NED, for F, evaluates nothing)
    where = {"pred_lat_deg": pred_lat_deg, "pred_lon_deg": pred_lon_deg, "sigma_m": sigma_m}
    values, gradient = element_values_and_gradient(model, elements, pred_lat_deg, pred_lon_deg, alt_m, year)
    model_f_nt = math.hypot(*model.ned_and_slopes(pred_lat_deg, pred_lon_deg, alt_m, year)[0].tolist())
    f_offset = f_offset_nt(model, elements, year, alt_m, f_nt, bias, pred_lat_deg, pred_lon_deg,
                           model_f_nt) - f_reference_nt
    if not math.isnan(f_nt) and not abs(f_offset) <= limits.f_band_nt:   # (NaN: F not measured, no band)
        return Judgement(False, "f_band", f_offset_nt=f_offset, **where)
    removed = bias if fix_bias is None else np.asarray(fix_bias, dtype=float)
    residual = elements.difference(np.asarray(measured, dtype=float) - removed, values)
    bound = limits.sigma_k * sigma_m + limits.speed_slack * flown_m + limits.margin_m
    if smallest_singular_value(gradient) < MIN_GRADIENT_SV:
        return Judgement(True, f_offset_nt=f_offset, bound_m=bound, **where)
    inverse = inverse2(gradient)
    noise_m = 0.0
    if noise is not None:
        spread = inverse * np.asarray(noise, dtype=float)             # G^-1 diag(sigma): its Frobenius norm
        noise_m = limits.sigma_k * float(np.sqrt(np.sum(spread * spread)))   # is sqrt(trace(G^-1 R G^-T))
        bound += noise_m
    offset = inverse @ residual
    jump = float(np.hypot(*offset))
    implied = (float(offset[0]), float(offset[1]))
    if not jump <= bound:
        return Judgement(False, "fix_jump", f_offset_nt=f_offset, jump_m=jump, bound_m=bound, noise_m=noise_m,
                         offset_en_m=implied, **where)
    return Judgement(True, f_offset_nt=f_offset, jump_m=jump, bound_m=bound, noise_m=noise_m, offset_en_m=implied,
                     **where)


class MagPlausibility:
    """Consecutive exclusions and what to say about them (the app's words go through ``say``)."""

    def __init__(self, limits: PlausibilityLimits = PlausibilityLimits(),
                 reanchor: ReanchorSettings = ReanchorSettings()) -> None:
        self.limits = limits
        self.in_a_row = 0
        self.excluded = 0
        self.reanchored = 0
        self.consensus = OffsetConsensus(reanchor)
        self.f_reference_nt: float | None = None   # |F| level at the mission's first step (f_offset_nt)

    def agreed_shift(self, judgement: Judgement, period_m: float, steps: int) -> tuple[np.ndarray, float] | None:
        """For an excluded ``judgement``: (shift east/north m, its 1-sigma m) when this exclusion
        and the ``steps - 1`` before it agree on the offset from the prediction (the estimate is
        wrong), else None. ``period_m``: the distance flown in one period (dead-reckoning slack
        between the agreeing fixes); ``steps``: NAV_REANCHOR_N (0: never). Any other verdict
        ends the run."""
        if steps != self.consensus.settings.steps:
            self.consensus.settings = replace(self.consensus.settings, steps=steps)
        if judgement.ok or judgement.kind != "fix_jump":
            self.consensus.clear()
            return None
        slack = judgement.noise_m + self.limits.speed_slack * period_m
        shift = self.consensus.rejected(np.array(judgement.offset_en_m), extra_tolerance_m=slack)
        if shift is None:
            return None
        self.reanchored += 1
        self.in_a_row = 0
        sigma = math.hypot(judgement.noise_m / self.limits.sigma_k, 0.5 * self.consensus.settings.tolerance_m)
        return shift, sigma

    def reanchor_words(self, shift_en_m: np.ndarray) -> str:
        n = self.consensus.settings.steps
        return (f"FcMPC: {n} excluded fixes agree: estimate re-anchored "
                f"{float(np.hypot(*shift_en_m)) / 1000.0:.1f} km")

    def taken_anyway(self) -> int:
        """The period just judged implausible is taken all the same (NAV_EXCL_MAX): it no longer counts
        as excluded and the run in a row ends. Returns how many periods were excluded in a row before it."""
        before, self.in_a_row = self.in_a_row - 1, 0
        self.excluded -= 1
        return before

    def verdict(self, judgement: Judgement) -> tuple[str, str] | None:
        """(severity name, text) to say for this judgement, or None to say nothing."""
        if judgement.ok:
            if not self.in_a_row:
                return None
            n, self.in_a_row = self.in_a_row, 0
            return "NOTICE", f"FcMPC: magnetometer plausible again after {n} excluded step{'s' * (n > 1)}"
        self.in_a_row += 1
        self.excluded += 1
        if self.in_a_row == self.limits.sustained_steps:
            return "CRITICAL", (f"FcMPC: sustained magnetometer offset ({self.in_a_row} steps): "
                                f"{judgement.words()}, excluded")
        return "WARNING", f"FcMPC: implausible magnetometer step: {judgement.words()}, excluded"

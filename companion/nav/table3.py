"""Table 3's position estimate: the geomagnetic fix alone, fused with the INS where it is weak.

``FUS_MODEL 1`` (and auto without an independent INS): each cruise step's geomagnetic fix
(eq. 49, Newton from the dead-reckoned prior, on the steering pair with the start-up
calibration already removed) is the position, unless it is weak (Algorithm 1's min |G| < sigma,
read as the smallest singular value of the model's G at the fix in degrees per metre, F counted
at ``F_NT_PER_DEG``: the estimated G is too noisy to judge the fix by) or failed; then, with an
INS, the paper's INS/geomagnetic fusion (eq. 46-58, :mod:`companion.nav.fusion`) gives it.

A fix farther than ``NAV_FIX_GATE_M`` from the dead-reckoned position is a wrong contour
crossing or a disturbed measurement and is dropped, unless there is no INS and the last
``NAV_REANCHOR_N`` dropped fixes agree on where the vehicle is (:mod:`companion.nav.reanchor`):
then the estimate is what is wrong, and the fix is taken.
"""
from __future__ import annotations

import math

import numpy as np

from companion.nav.elements import ElementSet
from companion.nav.field import PositionFixError, WorldMagneticModel, element_fix
from companion.nav.fusion import FusionSettings, InsGeomagFusion
from companion.nav.geo import enu_offset, geodesic_inverse, offset_position
from companion.nav.reanchor import OffsetConsensus, ReanchorSettings
from companion.params import NavConfig

__all__ = ["F_NT_PER_DEG", "Table3Estimator"]

F_NT_PER_DEG = 360.0   # automatic bounds and the fusion gate: a degree of D or I counts as 360 nT of F


class Table3Estimator:
    """The fix, the gate, and the Table 3 fusion filter; ``rejected`` counts dropped fixes."""

    def __init__(self, config: NavConfig, model: WorldMagneticModel, elements: ElementSet) -> None:
        self.config, self.model, self.elements = config, model, elements
        self.fusion = InsGeomagFusion(FusionSettings(config.fusion_qc_m2, config.fusion_rc_m2,
                                                     config.fusion_p0_m2, config.fusion_feedback))
        self.consensus = OffsetConsensus(ReanchorSettings(steps=config.reanchor_steps))
        self.rejected = 0
        self._degree_equivalent = np.array([F_NT_PER_DEG if n.endswith("_nt") else 1.0 for n in elements.names])

    def estimate(self, est: tuple[float, float], s: np.ndarray, lag_en_m: np.ndarray, ins_lat_deg: float,
                 ins_lon_deg: float) -> tuple[tuple[float, float], tuple[float, float], bool, float]:
        """(position, fix or NaNs, fused with the INS, 1-sigma m) for the step whose dead-reckoned
        position is ``est``, measuring ``s`` at the window centre ``lag_en_m`` behind it."""
        c = self.config
        have_ins = math.isfinite(ins_lat_deg) and math.isfinite(ins_lon_deg)
        lag_e, lag_n = (float(v) for v in lag_en_m)
        prior = offset_position(est[0], est[1], -lag_e, -lag_n)
        try:
            found = element_fix(self.model, self.elements, s, float(prior[0]), float(prior[1]), c.alt_m, c.year)
            fix = tuple(float(v) for v in offset_position(found.lat_deg, found.lon_deg, lag_e, lag_n))
            # the fix is as good as the field's gradient where it lands (an error e moves it G^-1 e)
            in_degrees = found.gradient / self._degree_equivalent[:, None]
            weak = float(np.linalg.svd(in_degrees, compute_uv=False)[-1]) < c.fusion_sigma_deg_per_m
        except PositionFixError:
            fix, weak = None, True
        if fix is not None and geodesic_inverse(est[0], est[1], *fix)[0] > c.fix_gate_m:
            # farther from the dead-reckoned position than the vehicle can have strayed in a step
            # (a wrong crossing of the contours, a disturbed measurement): not a fix, unless the
            # last rejected fixes agree on where the vehicle is (the estimate is what is wrong)
            if have_ins or self.consensus.rejected(np.array(enu_offset(est[0], est[1], *fix))) is None:
                fix, weak = None, True
                self.rejected += 1
        elif fix is not None:
            self.consensus.clear()
        position, fused, sigma = est, False, math.sqrt(c.fusion_rc_m2)
        if weak and have_ins:
            ins_en = np.array(enu_offset(c.start_lat_deg, c.start_lon_deg, ins_lat_deg, ins_lon_deg))
            if fix is not None:
                result = self.fusion.step(ins_en, np.array(enu_offset(c.start_lat_deg, c.start_lon_deg, *fix)))
            else:
                result = self.fusion.predict_only(ins_en)
            position = tuple(float(v) for v in offset_position(c.start_lat_deg, c.start_lon_deg,
                                                               result.east_m, result.north_m))
            fused, sigma = True, result.sigma_m
        elif fix is not None:
            position = fix
        return position, (fix if fix is not None else (math.nan, math.nan)), fused, sigma

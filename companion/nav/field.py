"""World Magnetic Model, element gradients and the geomagnetic position fix: one import path.

The navigation state is the pair of magnetic elements ``S = (D, I)`` of the paper's eq. 1-2
(degrees; D positive east, I positive down; see :mod:`companion`). The code lives in three
modules, one idea each, and is re-exported here so callers keep one import:

* :mod:`companion.nav.harmonics`: the spherical-harmonic sums of a degree-12 model (the WMM
  technical report's algorithm), pure numpy; :mod:`companion.nav.highdegree` the same sums at
  any degree by the stable recursion (WMMHR-2025, degree 133);
* :mod:`companion.nav.wmm`: :class:`WorldMagneticModel` (NOAA ``.COF`` files, by default the
  copies shipped with pygeomag; validity span; :class:`FieldElements`), :func:`load_wmm`,
  :func:`model_for_date`, :func:`model_for_setting` (NAV_WMM, and NAV_MAP's choice of WMM or WMMHR);
* :mod:`companion.nav.fix`: :func:`decl_incl_gradient` / :func:`element_gradient` (G in element
  units per metre) and :func:`geomagnetic_fix` / :func:`element_fix` (eq. 49, Newton from a prior), :func:`fix_covariance`.
"""
from __future__ import annotations

from companion.nav.fix import (
    PositionFix,
    PositionFixError,
    decl_incl_gradient,
    element_fix,
    element_gradient,
    element_values_and_gradient,
    fix_covariance,
    geomagnetic_fix,
)
from companion.nav.harmonics import WMM_DEGREE, schmidt_polynomials
from companion.nav.wmm import (
    WMM2025_SWITCH_YEAR,
    FieldElements,
    WorldMagneticModel,
    load_wmm,
    model_for_date,
    model_for_setting,
)

__all__ = [
    "WMM2025_SWITCH_YEAR",
    "WMM_DEGREE",
    "FieldElements",
    "PositionFix",
    "PositionFixError",
    "WorldMagneticModel",
    "decl_incl_gradient",
    "element_fix",
    "element_gradient",
    "element_values_and_gradient",
    "fix_covariance",
    "geomagnetic_fix",
    "load_wmm",
    "model_for_date",
    "model_for_setting",
    "schmidt_polynomials",
]

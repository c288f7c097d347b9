"""Which magnetic elements the navigator measures and steers on: the navigation state S.

The paper navigates on ``S = (D, I)`` (eq. 1-2). Declination needs a heading reference that is
independent of the magnetometer: ``D = heading_of_the_field - yaw``. On ArduPilot and PX4 the
flight controller's yaw comes from this same compass and a declination table evaluated at the
flight controller's own position, so D measured against it is that table value plus the yaw
error: no position information at all. The heading-free pair ``(I, F)``, inclination and total
intensity, needs only the magnetometer (F) and the gravity-referenced tilt (I); it carries the
same information as ``(H, Z)`` (a change of coordinates); both are offered, because their noise
and their biases differ (a hard-iron residual moves Z and H unlike I and F).

Sets (NAV_ELEMENTS): 1 ``(D, I)`` (the paper), 2 ``(I, F)``, 3 ``(H, Z)`` (heading-free), 4
``(D, I, F)``: all three measured and weighted by each element's declared noise in the
navigation filter (:mod:`companion.nav.navfilter`), the MPC steering on its first two,
``(D, I)`` (:meth:`ElementSet.steering`), whose geomagnetic fix (eq. 49) is also the one
reported beside the filter's estimate; F is set aside while a space-weather index declares a
storm. 5 ``(D, I, F)`` with F weighed only while an index says the field is quiet (auto with an
independent heading): without a space-weather feed it is ``(D, I)``, and F is never trusted on
a day nobody vouches for (:meth:`ElementSet.measured_rows`).

Each :class:`ElementSet` says which two elements form S, in which unit each enters the state
(degrees for angles, nanotesla for intensities), how a difference is formed (declination wraps
at +-180 deg) and how many QP units one element unit is (:meth:`ElementSet.qp_scale`), so that
the MPC (eq. 13-38) sees both elements on comparable scales.

Conditioning on the paper's Pacific route (WMM2020, 2024.36): grad D points at -42 deg (from
east, counter-clockwise), grad I at +88..+94 deg, grad F at +114..+117 deg. (D, I) are 130 deg
apart, well conditioned; (I, F) only 23-27 deg apart, so a fix on (I, F) is about 2.3 times
less certain across the I/F contours than along them (1 / sin 25 deg): the price of not
needing a heading.

>>> ELEMENT_SETS[ElementSet.HEADING_FREE].names
('incl_deg', 'f_nt')
>>> float(ELEMENT_SETS[ElementSet.PAPER].difference([179.0, 40.0], [-179.0, 39.0])[0])
-2.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["ElementSet", "ELEMENT_SETS", "element_set", "ELEMENT_NAMES", "STANDARD_ERROR_NAMES", "hz_standard_errors",
           "resolve_elements"]

ARCSEC_PER_DEG = 3600.0
# One QP unit per 0.1 nT: a cruise step (5 km) on the Pacific route changes F by 10-25 nT,
# i.e. 100-250 units, the same order as I's 50-200 arcsec, so Q = I weighs both alike.
QP_UNITS_PER_NT = 10.0
# Paper units (MPC_UNITS = 1) keep degrees for angles; F then enters in hundreds of nT, so a
# degree of I and 100 nT of F (each about 100 km of travel here) count alike.
PAPER_UNITS_PER_NT = 0.01

ELEMENT_NAMES = {"decl_deg": "D", "incl_deg": "I", "f_nt": "F", "h_nt": "H", "z_nt": "Z"}
# the attribute holding each element's measured standard error (Measurement; PeriodAverage has D, I and F)
STANDARD_ERROR_NAMES = {"decl_deg": "decl_se_deg", "incl_deg": "incl_se_deg", "f_nt": "f_se_nt",
                        "h_nt": "h_se_nt", "z_nt": "z_se_nt"}


@dataclass(frozen=True)
class ElementSet:
    """Two magnetic elements forming the navigation state S.

    ``names``: attribute names of :class:`companion.nav.field.FieldElements` (and of
    :class:`companion.nav.mission.Measurement`), in state order (two, or three for a weighted
    set). ``code``: the NAV_ELEMENTS value.
    """

    code: int
    names: tuple[str, ...]

    PAPER = 1          # (D, I): needs an independent heading
    HEADING_FREE = 2   # (I, F): magnetometer and tilt only
    HORIZONTAL_VERTICAL = 3   # (H, Z): magnetometer and tilt only
    WEIGHTED = 4       # (D, I, F): all three, weighted by declared noise; steers on (D, I)
    WEIGHTED_WHEN_QUIET = 5   # (D, I, F), F weighed only while a space-weather index says quiet

    @property
    def label(self) -> str:
        """Short label such as ``"(D, I)"``."""
        return "(" + ", ".join(ELEMENT_NAMES[n] for n in self.names) + ")"

    @property
    def uses_declination(self) -> bool:
        return "decl_deg" in self.names

    @property
    def heading_free(self) -> bool:
        return not self.uses_declination

    @property
    def weighted(self) -> bool:
        """A weighted set: D and I with F beside them (sets 4 and 5), F weighed by the rules of
        :meth:`measured_rows`."""
        return len(self.names) == 3 and "f_nt" in self.names

    def measured_rows(self, declared: bool, index_quiet: bool) -> tuple[int, ...]:
        """The indices of the elements the navigation filter measures this step.

        ``declared``: a space-weather index (Kp or SYM-H,
        :func:`companion.nav.disturbance.storm_declared`) declares a storm; ``index_quiet``: a fresh
        index says the field is quiet. A pair keeps both elements. A weighted set sets F aside
        while a storm is declared, and set 5 also while no index says quiet.
        Why: a storm's ring current moves the total intensity most, by tens to hundreds of nT
        against F's few nT of quiet noise, and what the SYM-H prediction and the bias states' walk
        leave of it was read as position: on the ideal storms (D, I, F) ended 4.78 / 7.30 km off
        where (D, I) ends 2.91 / 3.51 km, and with F set aside 2.91 / 3.51 km (50 seeds each,
        2026-12-04). Without an index the storm drags F before the innovations recognise it
        (README, "Element sets"), so set 5 weighs F only on a day an index vouches for.

        >>> [ELEMENT_SETS[c].measured_rows(d, q) for c, d, q in ((4, False, False), (4, True, False), (5, False, False),
        ...                                                      (5, False, True), (1, True, False))]
        [(0, 1, 2), (0, 1), (0, 1), (0, 1, 2), (0, 1)]
        """
        if not self.weighted:
            return tuple(range(len(self.names)))
        if declared or (self.code == self.WEIGHTED_WHEN_QUIET and not index_quiet):
            return tuple(i for i, name in enumerate(self.names) if name != "f_nt")
        return tuple(range(len(self.names)))

    @property
    def f_condition(self) -> str:
        """When a weighted set weighs F, in words ("" for a pair)."""
        if self.code == self.WEIGHTED_WHEN_QUIET:
            return "F weighed only while NAV_KP or NAV_SYMH, fresh, says quiet"
        return "F set aside while a storm is declared" if self.weighted else ""

    def steering(self) -> "ElementSet":
        """The two elements the MPC steers on: the set itself, or the first two of a weighted set."""
        return self if len(self.names) == 2 else ElementSet(self.code, self.names[:2])

    def values(self, source) -> np.ndarray:
        """The two elements of ``source`` (FieldElements, Measurement or any object with the names)."""
        return np.array([getattr(source, name) for name in self.names], dtype=float)

    def standard_errors(self, source) -> np.ndarray:
        """The measured standard errors of the set's elements in ``source`` (NaN where it has none)."""
        return np.array([getattr(source, STANDARD_ERROR_NAMES[name], math.nan) for name in self.names], dtype=float)

    def difference(self, a: ArrayLike, b: ArrayLike) -> np.ndarray:
        """``a - b`` element-wise, declination wrapped into [-180, 180) degrees."""
        diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        if self.uses_declination:
            k = self.names.index("decl_deg")
            diff[..., k] = (diff[..., k] + 180.0) % 360.0 - 180.0
        return diff

    def qp_scale(self, mpc_units: int) -> np.ndarray:
        """QP state units per element unit: arc-seconds per degree and 0.1 nT (scaled, default),
        or degrees and hundreds of nT (MPC_UNITS = 1, the paper's degrees)."""
        per_deg = 1.0 if mpc_units == 1 else ARCSEC_PER_DEG
        per_nt = PAPER_UNITS_PER_NT if mpc_units == 1 else QP_UNITS_PER_NT
        return np.array([per_nt if name.endswith("_nt") else per_deg for name in self.names])

    def finite(self, source) -> bool:
        return all(math.isfinite(getattr(source, name)) for name in self.names)


ELEMENT_SETS: dict[int, ElementSet] = {
    ElementSet.PAPER: ElementSet(ElementSet.PAPER, ("decl_deg", "incl_deg")),
    ElementSet.HEADING_FREE: ElementSet(ElementSet.HEADING_FREE, ("incl_deg", "f_nt")),
    ElementSet.HORIZONTAL_VERTICAL: ElementSet(ElementSet.HORIZONTAL_VERTICAL, ("h_nt", "z_nt")),
    ElementSet.WEIGHTED: ElementSet(ElementSet.WEIGHTED, ("decl_deg", "incl_deg", "f_nt")),
    ElementSet.WEIGHTED_WHEN_QUIET: ElementSet(ElementSet.WEIGHTED_WHEN_QUIET, ("decl_deg", "incl_deg", "f_nt")),
}


def resolve_elements(requested: int, compass_derived: bool) -> int:
    """NAV_ELEMENTS against the heading source: with a compass-derived yaw never D ((D, I) and
    (D, I, F) become (I, F); (H, Z) stays); auto (0) is set 5 with an independent heading, (D, I, F)
    with F weighed only while a space-weather index says quiet, and (I, F) without one. Why not
    set 4 for auto: without a space-weather index (NAV_KP unknown, the default) a storm drags F
    before the innovations recognise it (README, "Element sets"); set 5 is then (D, I).

    >>> resolve_elements(0, True), resolve_elements(0, False), resolve_elements(4, True), resolve_elements(3, True)
    (2, 5, 2, 3)
    """
    if compass_derived:
        return requested if requested == ElementSet.HORIZONTAL_VERTICAL else ElementSet.HEADING_FREE
    return ElementSet.WEIGHTED_WHEN_QUIET if requested == 0 else requested


def hz_standard_errors(f_nt: float, incl_deg: float, f_se_nt: float, incl_se_deg: float) -> tuple[float, float]:
    """Standard errors of ``H = F cos I`` and ``Z = F sin I`` from those of F and I, to first
    order, the errors of F and I taken as independent (NaN where either is unknown).

    >>> [round(v, 6) for v in hz_standard_errors(50000.0, 0.0, 3.0, math.degrees(4.0 / 50000.0))]
    [3.0, 4.0]
    """
    c, s = math.cos(math.radians(incl_deg)), math.sin(math.radians(incl_deg))
    se_i = math.radians(incl_se_deg) * f_nt
    return math.hypot(c * f_se_nt, s * se_i), math.hypot(s * f_se_nt, c * se_i)


def element_set(code: int) -> ElementSet:
    """The element set of a NAV_ELEMENTS value (1-5); ValueError otherwise (0, auto, is
    resolved by the caller, who knows the heading source)."""
    try:
        return ELEMENT_SETS[int(code)]
    except (KeyError, ValueError, TypeError):
        raise ValueError(f"NAV_ELEMENTS {code!r} is not a concrete element set "
                         "(1 (D, I), 2 (I, F), 3 (H, Z), 4 (D, I, F), 5 (D, I, F) with F while quiet)") from None

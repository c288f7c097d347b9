"""The ring current's field predicted from the SYM-H index, taken out of each measurement.

A magnetic storm's main phase at low and middle latitudes is mostly the ring current: a westward
current around the Earth at a few Earth radii that lowers the horizontal intensity H everywhere
at once, by up to hundreds of nT over hours. The SYM-H index (Kyoto World Data Center; one value a
minute, published in near real time, also in NASA's OMNI data) is that change of H, measured at
six mid-latitude observatories and referred to the dipole equator; Dst is its hourly form.

**Model.** Since a reference time ``t0`` (the mission's start-up average, where the start-up
calibration took up whatever disturbance was there), the ring current moves the field at the
vehicle by ``dH = K (SYMH(t) - SYMH(t0))`` along the local horizontal field, ``dB = dH (N/H, E/H,
0)``, with ``K`` = ``FUS_SYMH_K``. Along its own direction, a change of H leaves D alone and moves
``I`` by ``-Z / F^2 dH`` (rad) and ``F`` by ``H / F dH``. The navigator subtracts that change
from each measured element (:func:`ring_current_elements`); what the prediction misses walks as
the storm's north component (``FUS_SYMH_N``, ``FUS_SYMH_TN``; :mod:`companion.nav.disturbance`)
in place of ``FUS_BQA_N``, ``FUS_BQA_TN``.

Why these choices, measured along the Pacific route for the 10 May 2024 storm (the five
INTERMAGNET observatories of the simulated world, 18-24 UTC compressed onto the mission): the
disturbance's north component is 1.02 times the SYM-H change, its east -0.13 times (a direction
7 deg west of north, where the local D is 0-4 deg west and the dipole's north 7.5 deg east), its
down 0.12 times. The north's rms offset from the start falls from 221 to 42 nT once the
prediction is removed, and what is left wanders at about 61 nT per sqrt(hour) over short lags
but stays within about 50 nT (Gauss-Markov, correlation time 1.3 h), where without the
prediction it walked on to 350 nT. ``K`` 1: SYM-H is referred to the dipole equator, so a
symmetric ring current gives ``cos(geomagnetic latitude)`` (0.90-0.93 on this route) of it; the
measured 1.02 includes the night-side asymmetry and the Earth's induced currents. Z is left
alone: the induced currents cancel most of the ring current's vertical field.

**The feed.** A value of ``SYMH_UNKNOWN_ABOVE_NT`` or more is no value (the parameter's default,
99999, is OMNI's own fill value); the deepest storms on record took SYM-H to about -700 nT.
Without a value at the start there is no reference and no correction all mission; a value
missing later holds the last one (the ring current does not vanish with the feed).

>>> round(ring_current_change_nt(1.0, -250.0, -50.0), 1)
-200.0
>>> ring_current_elements(("incl_deg", "f_nt"), 30000.0, 0.0, 40000.0, -100.0).round(4).tolist()
[0.0917, -60.0]
"""
from __future__ import annotations

import math

import numpy as np

from companion.nav.disturbance import field_jacobian

__all__ = ["SYMH_UNKNOWN_ABOVE_NT", "ring_current_change_nt", "ring_current_elements", "symh_value"]

SYMH_UNKNOWN_ABOVE_NT = 3000.0   # a SYM-H at or above this (nT) is no value: the feed's "unknown"


def symh_value(symh_nt: float) -> float:
    """A SYM-H reading in nT, or NaN when it is no value (non-finite, or the feed's "unknown")."""
    value = float(symh_nt)
    return value if math.isfinite(value) and value < SYMH_UNKNOWN_ABOVE_NT else math.nan


def ring_current_change_nt(ratio: float, symh_nt: float, reference_nt: float) -> float:
    """``dH`` (nT): the ring current's change of the horizontal intensity at the vehicle since the
    reference, ``ratio (SYMH - SYMH_ref)``; NaN when either reading is missing."""
    return float(ratio) * (float(symh_nt) - float(reference_nt))


def ring_current_elements(names: tuple[str, ...], north_nt: float, east_nt: float, down_nt: float,
                          delta_h_nt: float) -> np.ndarray:
    """How much each named element (``decl_deg``, ``incl_deg``, ``f_nt``, ``h_nt``, ``z_nt``)
    changes when the horizontal intensity of the field ``(N, E, Z)`` (nT) changes by
    ``delta_h_nt`` along its own direction (degrees for angles, nT for intensities)."""
    h = math.hypot(north_nt, east_nt)
    along_h = np.array([north_nt / h, east_nt / h, 0.0])
    return field_jacobian(names, north_nt, east_nt, down_nt) @ along_h * float(delta_h_nt)

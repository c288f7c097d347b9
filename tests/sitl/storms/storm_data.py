"""Where the real May 2024 files are, and independent helpers (standard library and regex, not
the module under test) the storm tests share.
"""
from __future__ import annotations

import re
from datetime import datetime, timezone
from pathlib import Path

import numpy as np


INTERMAGNET = ("storms", "intermagnet")
OMNI = ("storms", "omni_hro2_1min_20240509-13_symh_ae.csv")
KP = ("storms", "gfz_Kp_ap_Ap_SN_F107_2024-04-21_to_2024-06-30_excerpt.txt")
# Station positions as printed in the data README (geodetic, degrees east 0..360).
README_POSITIONS = {
    "kak": (36.232, 140.186),
    "gua": (13.588, 144.867),
    "cta": (-20.090, 146.260),
    "cnb": (-35.317, 149.367),
    "frd": (38.205, 282.627),
}
WESTERN_PACIFIC = ("kak", "gua", "cta", "cnb")


def posix(text: str) -> float:
    """POSIX seconds of 'YYYY-MM-DD HH:MM[:SS]' UTC, by the standard library (not the module)."""
    return datetime.fromisoformat(text.replace(" ", "T")).replace(tzinfo=timezone.utc).timestamp()


def raw_values(path: Path, stamp: str) -> tuple[float, float, float, float]:
    """The four values of the IAGA-2002 line stamped `stamp`, by regex on the raw text."""
    match = re.search(rf"^{re.escape(stamp)}\s+\d+\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s*$", path.read_text(), re.M)
    assert match, f"{stamp} not in {path}"
    return tuple(float(v) for v in match.groups())  # type: ignore[return-value]


def quiet_median(values: np.ndarray, time_s: np.ndarray) -> float:
    inside = (time_s >= posix("2024-05-10 12:00")) & (time_s < posix("2024-05-10 17:00"))
    return float(np.median(values[inside]))

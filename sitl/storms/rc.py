"""RC reader: the hourly RC ring-current index of the CHAOS field models (DTU Space; Olsen et al.
2014, GJI 197, doi:10.1093/gji/ggu033), from the HDF5 file ChaosMagPy ships (``RC_index.h5``).

Datasets ``time`` (days since 2000-01-01 00:00 UTC, stamped at :30 of each hour: the hour's
centre), ``RC``, ``RC_e``, ``RC_i`` (nT), ``flag``. Read with h5py, the standard HDF5 binding.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sitl.storms.common import StormDataError, utc_s
from sitl.storms.published import IndexSeries

__all__ = ["RC_FILE", "read_rc_index"]

#: The RC file under the shared data folder.
RC_FILE = ("indices", "RC_index.h5")
_EPOCH_2000_S = utc_s("2000-01-01T00:00")


def read_rc_index(path: str | os.PathLike[str], start_s: float = -np.inf, end_s: float = np.inf) -> IndexSeries:
    """The RC index (nT) as hourly intervals, those overlapping ``[start_s, end_s]`` (POSIX UTC).

    Raises:
        StormDataError: no ``time``/``RC`` dataset, a time not at the half hour, or no row in the span.
    """
    import h5py   # the HDF5 standard; imported here so the other storm readers need no HDF5

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            days = np.asarray(f["time"][:], dtype=np.float64)
            rc = np.asarray(f["RC"][:], dtype=np.float64)
    except KeyError as err:
        raise StormDataError(path, None, f"no dataset {err} (need 'time' and 'RC')") from None
    except OSError as err:
        raise StormDataError(path, None, f"not an HDF5 file: {err}") from None
    centre = _EPOCH_2000_S + np.round(days * 86400.0)
    start = centre - 1800.0
    if (np.mod(start, 3600.0) != 0.0).any():
        raise StormDataError(path, None, "RC times must be at the half hour (hourly means)")
    keep = (start + 3600.0 > start_s) & (start <= end_s)
    if not keep.any():
        raise StormDataError(path, None, "no RC value in the requested span")
    return IndexSeries("RC", start[keep], 3600.0, rc[keep])

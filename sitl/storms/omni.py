"""OMNI reader: the 1-minute AE and SYM-H indices (NASA OMNIWeb CSV) that document the storm.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sitl.storms.common import FloatArray, StormDataError
from sitl.storms.published import IndexSeries

__all__ = ["OmniIndices", "read_omni_symh"]

# OMNI fill values of the AE / SYM-H columns (and of the other columns of the CSV).
_OMNI_FILL = (9999.99, 99999.9, 99999.0, 999999.0)


@dataclass(frozen=True, eq=False)
class OmniIndices:
    """OMNI 1-minute AE and SYM-H indices.

    ``time_s`` POSIX seconds UTC as stamped in the file (the file header says the stamps
    are the beginning of each averaging bin); ``ae_nt``, ``symh_nt`` in nT, NaN for fill
    values (9999.99 / 99999.9 / 99999).
    """

    time_s: FloatArray
    ae_nt: FloatArray
    symh_nt: FloatArray
    source: Path

    def series(self) -> IndexSeries:
        """The definitive SYM-H as 1-minute bins (:class:`~sitl.storms.published.IndexSeries`)."""
        return IndexSeries("SYM-H", self.time_s, 60.0, self.symh_nt)

    def symh_at(self, posix_s: float) -> float:
        """SYM-H (nT) at a POSIX time, linear between the bins' centres (each stamp is a bin's
        start); NaN outside the record or next to a fill value. The truth (it reaches up to 30 s
        into the next bin), not what a feed has at that time (:mod:`sitl.storms.published`)."""
        centres = self.time_s + 30.0
        t = float(posix_s)
        if not centres[0] <= t <= centres[-1]:
            return float("nan")
        return float(np.interp(t, centres, self.symh_nt))


def read_omni_symh(path: str | os.PathLike[str]) -> OmniIndices:
    """Read the CDAWeb OMNI CSV: ``#`` comment lines, one column header line, then rows.

    The columns are found by name in the header line (``EPOCH_TIME...``, ``...AE...``,
    ``SYM/H...``); times are ISO ``2024-05-09T06:00:00.000Z``.

    Raises:
        StormDataError: no header line, missing columns, a malformed or truncated row
            (wrong number of fields, unparsable time or number), times not increasing.
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    cols: list[str] | None = None
    i_ae = i_sym = -1
    times: list[np.datetime64] = []
    ae: list[float] = []
    sym: list[float] = []
    for line_no, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if cols is None:
            if not fields[0].upper().startswith("EPOCH"):
                raise StormDataError(path, line_no, f"expected the 'EPOCH_TIME,...' column header, got {line!r}")
            cols = [f.upper() for f in fields]
            i_ae = next((i for i, c in enumerate(cols) if re.search(r"(^|[^A-Z])AE([^A-Z]|$)", c)), -1)
            i_sym = next((i for i, c in enumerate(cols) if c.startswith("SYM/H") or c.startswith("SYM_H")), -1)
            if i_ae < 0 or i_sym < 0:
                raise StormDataError(path, line_no, f"no AE and SYM/H columns in {line!r}")
            continue
        if len(fields) != len(cols):
            raise StormDataError(
                path, line_no, f"expected {len(cols)} comma-separated fields, got {len(fields)} (truncated?): {line!r}"
            )
        try:
            stamp = np.datetime64(fields[0].rstrip("Z"), "ms")
            a, s = float(fields[i_ae]), float(fields[i_sym])
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse time/AE/SYM-H in {line!r}") from None
        if times and stamp <= times[-1]:
            raise StormDataError(path, line_no, f"time {fields[0]} does not increase")
        times.append(stamp)
        ae.append(a)
        sym.append(s)
    if cols is None or not times:
        raise StormDataError(path, len(lines), "no data rows (truncated file?)")
    ae_arr = np.asarray(ae)
    sym_arr = np.asarray(sym)
    for arr in (ae_arr, sym_arr):
        arr[np.isclose(arr[:, None], np.asarray(_OMNI_FILL)[None, :], rtol=0.0, atol=1e-6).any(axis=1)] = np.nan
    time_s = np.asarray(times, dtype="datetime64[ms]").astype(np.int64).astype(np.float64) / 1000.0
    return OmniIndices(time_s=time_s, ae_nt=ae_arr, symh_nt=sym_arr, source=path)

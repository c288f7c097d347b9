"""sitl.storms.omni and sitl.storms.kp: the OMNI SYM-H/AE and GFZ Kp readers.

Expected values are read from the raw file text by regular expressions (not by the reader
under test) or computed from physics, never copied from the implementation.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from sitl import storms as S
from tests.sitl.storms.storm_data import KP, OMNI, posix


# ------------------------------------------------------------------------------ indices


def test_omni_symh_minimum(shared_data: Path, tmp_path: Path) -> None:
    path = shared_data.joinpath(*OMNI)
    omni = S.read_omni_symh(path)
    text = path.read_text()
    assert omni.time_s.size == len(re.findall(r"^\d{4}-\d\d-\d\dT", text, re.M))
    k = int(np.nanargmin(omni.symh_nt))
    assert omni.symh_nt[k] == -518.0
    assert omni.time_s[k] == posix("2024-05-11 02:14")
    raw = re.search(r"^2024-05-11T02:14:00\.000Z,.*,(-?\d+)\s*$", text, re.M)
    assert raw and float(raw.group(1)) == -518.0
    assert np.isfinite(omni.ae_nt).all() and omni.ae_nt.max() > 2000.0  # AE during the storm

    # Fill values become NaN; a truncated row names its line.
    lines = text.splitlines()
    i = next(n for n, line in enumerate(lines) if line.startswith("2024-05-11T02:14"))
    fields = lines[i].split(",")
    fields[-2], fields[-1] = "9999.99", "99999.9"
    lines[i] = ",".join(fields)
    bad = tmp_path / "omni.csv"
    bad.write_text("\n".join(lines) + "\n")
    filled = S.read_omni_symh(bad)
    assert np.isnan(filled.symh_nt[k]) and np.isnan(filled.ae_nt[k])
    assert np.nanmin(filled.symh_nt) > -518.0
    bad.write_text("\n".join(lines[: i + 1] + [lines[i + 1][:30]]))
    with pytest.raises(S.StormDataError, match=re.escape(f"{bad}:{i + 2}:")):
        S.read_omni_symh(bad)


def test_gfz_kp(shared_data: Path, tmp_path: Path) -> None:
    path = shared_data.joinpath(*KP)
    kp = S.read_gfz_kp(path)
    raw = re.search(r"^2024 05 11 .*$", path.read_text(), re.M)
    assert raw
    kp1 = float(raw.group(0).split()[7])
    assert kp1 == 9.0
    assert kp.kp_at(posix("2024-05-11 00:00")) == kp1
    assert kp.kp_at(posix("2024-05-11 02:59:59")) == 9.0
    assert kp.kp_at(posix("2024-05-06 01:00")) == pytest.approx(5.333)  # README: Kp 5+ 00-03 UTC
    assert kp.kp_at(posix("2024-05-10 22:00")) == pytest.approx(8.667)
    assert np.isnan(kp.kp_at([posix("2024-04-20 12:00"), posix("2024-07-01 01:00")])).all()
    assert np.all(np.diff(kp.day_s) == 86400.0)  # the excerpt's repeated 2024-05-06 row kept once
    assert kp.day_s.size == 71
    lines = path.read_text().splitlines()
    i = next(n for n, line in enumerate(lines) if line.startswith("2024 05 10"))
    bad = tmp_path / "kp.txt"
    bad.write_text("\n".join(lines[:i] + [lines[i][:60]]))
    with pytest.raises(S.StormDataError, match=re.escape(f"{bad}:{i + 1}:")):
        S.read_gfz_kp(bad)

"""sitl.storms.plot: the Fig. 5 plot carries the acknowledgement.

Expected values are read from the raw file text by regular expressions (not by the reader
under test) or computed from physics, never copied from the implementation.
"""
from __future__ import annotations

from pathlib import Path


from sitl import storms as S


def test_plot_disturbance(tmp_path: Path, disturbance) -> None:
    out = tmp_path / "out" / "short_storm.png"
    fig = S.plot_disturbance(disturbance, out, S.SHORT_STORM)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from matplotlib.text import Text

    texts = [t.get_text() for t in fig.findobj(Text)]
    assert S.ACKNOWLEDGEMENT in texts
    assert "INTERMAGNET" in S.ACKNOWLEDGEMENT and "Geoscience Australia" in S.ACKNOWLEDGEMENT
    assert len(fig.axes) == 4
    assert len(fig.axes[1].get_lines()) == len(disturbance.stations)

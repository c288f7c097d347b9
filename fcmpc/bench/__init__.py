"""The benchmarks behind ``fcmpc-bench`` (issue 13): each part of the system timed beside its anchors.

:mod:`~fcmpc.bench.sections` times the parts (the QP, the field model, the fix, a mission step,
the Monte Carlo, the simulator, the companion's step) and returns rows of (benchmark, ours,
anchor, target); :mod:`~fcmpc.bench.table` merges repeated runs and prints the table.
``scripts/bench.py`` is the command line. Nothing here is asserted by the tests as a timing.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):   # before numpy loads
    os.environ.setdefault(_var, "1")

from fcmpc.bench.sections import QUICK_SECTIONS, SECTIONS, Row  # noqa: E402
from fcmpc.bench.table import format_rows, median_rows  # noqa: E402

__all__ = ["QUICK_SECTIONS", "Row", "SECTIONS", "format_rows", "median_rows"]

"""The benchmarks behind ``fcmpc-bench`` (issue 13): each part of the system timed beside its anchors.

:mod:`~fcmpc_bench.sections` times the parts (the QP, the field model, the fix, a mission step,
the Monte Carlo, the simulator, the companion's step) and returns rows of (benchmark, ours,
anchor, target); :mod:`~fcmpc_bench.table` merges repeated runs and prints the table.
``scripts/bench.py`` is the command line. Nothing here is asserted by the tests as a timing.
"""
from fcmpc_bench.sections import QUICK_SECTIONS, SECTIONS, Row
from fcmpc_bench.table import format_rows, median_rows

__all__ = ["QUICK_SECTIONS", "Row", "SECTIONS", "format_rows", "median_rows"]

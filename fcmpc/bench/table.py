"""The benchmark table: repeated runs of a section merged into median rows, and the rows printed."""
from __future__ import annotations

import re

from fcmpc.bench.sections import Row

__all__ = ["format_rows", "leading_number", "median_rows"]

_LEADING_NUMBER = re.compile(r"^\s*([-+]?[0-9]*\.?[0-9]+)")


def leading_number(figure: str) -> float | None:
    """The number a figure starts with ("37.1 us (p99 92)" -> 37.1); None if it starts with none
    (a failure, a name)."""
    number = _LEADING_NUMBER.match(figure)
    return float(number.group(1)) if number else None


def median_rows(runs: list[list[Row]]) -> list[Row]:
    """One row per benchmark from repeated runs of a section: the run whose figure is the median
    (the lower median for an even count), its anchors as that run printed them, and the range of
    the figures over the runs after it. Rows are matched by name; a row whose figure is not a
    number (a scenario name, a failure) is the first run's."""
    if len(runs) == 1:
        return list(runs[0])
    merged: list[Row] = []
    for row in runs[0]:
        same = [r for run in runs for r in run if r[0] == row[0]]
        values = [leading_number(r[1]) for r in same]
        if None in values:
            merged.append(row)
            continue
        order = sorted(range(len(values)), key=values.__getitem__)
        middle = same[order[(len(order) - 1) // 2]]
        merged.append((middle[0], f"{middle[1]} [{min(values):g}-{max(values):g}, {len(values)} runs]",
                       middle[2], middle[3]))
    return merged


def format_rows(rows: list[Row], head: Row = ("benchmark", "ours (median)", "anchor", "target")) -> str:
    """The table under ``head`` (by default: benchmark, ours (median), anchor, target)."""
    widths = [max(len(r[i]) for r in [head, *rows]) + 2 for i in range(4)]
    lines = ["".join(f"{c:<{w}}" for c, w in zip(head, widths)), "-" * sum(widths)]
    lines += ["".join(f"{c:<{w}}" for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)

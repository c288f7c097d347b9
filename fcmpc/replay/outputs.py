"""Writing an evaluation: ``table.md``, ``summary.json``, ``windows.csv`` and the plots."""
from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from fcmpc.replay.plots import write_plots
from fcmpc.replay.records import ReplayEvaluation, WindowRecord
from fcmpc.replay.report import format_report

__all__ = ["summary_dict", "write_outputs"]

def _json_clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    return value


def summary_dict(ev: ReplayEvaluation) -> dict[str, Any]:
    """Everything but the time series and per-window records, JSON-ready (NaN -> null)."""
    out = {k: getattr(ev, k) for k in ev.__dataclass_fields__ if k not in ("series", "windows")}
    out = {k: asdict(v) if hasattr(v, "__dataclass_fields__") else
           [asdict(x) for x in v] if isinstance(v, list) and v and hasattr(v[0], "__dataclass_fields__") else v
           for k, v in out.items()}
    return _json_clean(out)


def write_outputs(ev: ReplayEvaluation, out: Path, plots: bool = True) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "table.md", out / "summary.json", out / "windows.csv"]
    (out / "table.md").write_text(format_report(ev))
    (out / "summary.json").write_text(json.dumps(summary_dict(ev), indent=1, allow_nan=False))
    with open(out / "windows.csv", "w", newline="") as handle:
        names = list(WindowRecord.__dataclass_fields__)
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        for r in ev.windows:
            writer.writerow({k: getattr(r, k) for k in names})
    if plots:
        written += write_plots(ev, out)
    return written

"""The Monte Carlo script end to end on a few runs: table, CSV, JSON and plots written."""
from __future__ import annotations

import csv
import json

from scripts.montecarlo import main


def test_montecarlo_writes_table_and_results(tmp_path, capsys):
    code = main(["--scenario", "pacific", "--runs", "2", "--workers", "1", "--controllers", "ltv,fc",
                 "--out", str(tmp_path), "--quiet"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "Trajectory length (km)" in printed and "812.1" in printed  # the paper's figure beside ours
    out = tmp_path / "pacific"
    rows = list(csv.DictReader(open(out / "runs.csv")))
    assert {r["controller"] for r in rows} == {"LTV-MPC", "Fc-MPC"} and len(rows) == 4
    summary = json.loads((out / "summary.json").read_text())["summary"]
    fc_remaining = [float(r["remaining_km"]) for r in rows if r["controller"] == "Fc-MPC"]
    assert abs(summary["Fc-MPC"]["remaining_km"] - sum(fc_remaining) / 2) < 1e-9
    assert (out / "trajectories.png").stat().st_size > 10_000 and (out / "boxplots.png").is_file()

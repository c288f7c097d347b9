"""The Monte Carlo script end to end on a few runs: table, CSV, JSON and plots written."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from scripts.montecarlo import RunRow, main, outlier_fence_km, plot_results
from sitl.scenario import load_scenario


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


def _row(controller: str, seed: int, max_dev_km: float) -> RunRow:
    return RunRow(controller, seed, False, "arrived", "", 160, 0.3, 805.0, 0.17, max_dev_km / 10, max_dev_km, 80.0,
                  28.0, 158.0, float("nan"), 0.1)


def test_one_wandering_run_does_not_set_the_trajectory_frame():
    rng = np.random.default_rng(1)
    rows = [_row("Fc-MPC", s, d) for s, d in enumerate(rng.uniform(2.0, 4.0, 50))]
    rows += [_row("LTI-MPC", s, d) for s, d in enumerate(rng.uniform(2.0, 6.0, 49))] + [_row("LTI-MPC", 49, 5000.0)]
    fence = outlier_fence_km(rows, 799.0)
    assert max(r.max_dev_km for r in rows if r.max_dev_km < 1000) < fence < 5000.0
    assert fence >= 0.05 * 799.0                         # never tighter than 5 % of the route
    tight = [_row("Fc-MPC", s, 100.0 + s) for s in range(20)]   # all wide: the fence follows the runs
    assert outlier_fence_km(tight, 799.0) >= 119.0


def test_trajectory_plot_counts_the_runs_beyond_the_frame(tmp_path):
    scenario = load_scenario("pacific")
    lat = np.linspace(scenario.start_lat_deg, scenario.dest_lat_deg, 50)
    lon = np.linspace(scenario.start_lon_deg, scenario.dest_lon_deg, 50)
    rows = [_row("Fc-MPC", s, 3.0) for s in range(5)] + [_row("LTI-MPC", 0, 3.0), _row("LTI-MPC", 1, 5000.0)]
    tracks = [(lat, lon)] * 6 + [(lat - np.linspace(0, 40, 50), lon)]        # one run wanders 40 deg south
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figures = []
    original = plt.subplots
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plt, "subplots", lambda *a, **k: figures.append(original(*a, **k)) or figures[-1])
        mp.setattr(plt, "close", lambda fig: None)
        plot_results(tmp_path, scenario, rows, tracks, storm=False)
    ax = figures[0][1]
    assert ax.get_ylim()[0] > scenario.dest_lat_deg - 1.0            # the frame ignores the wanderer
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(label.startswith("LTI-MPC: 1 run(s) beyond the frame") and "5000 km" in label for label in labels)
    assert (tmp_path / "trajectories.png").stat().st_size > 10_000

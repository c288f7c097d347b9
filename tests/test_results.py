"""fcmpc-results: each table regenerated alone leaves the others as they were; the storm table shows
each storm's feed on / off / zero-delay cells with the storms its parameters were fitted on."""
from __future__ import annotations

import pytest

from fcmpc.montecarlo.results import STORM_VARIANTS, splice, storm_table


def _cell(median: float, storms: list[str]) -> dict:
    return {"median_km": median, "p90_km": 2 * median, "inside_pct": 94.0, "pred95_pct": 92.0, "runs": 50, "storms": storms,
            "symh_k": 0.5, "bqa_n": 57.0}


def test_a_table_regenerated_alone_leaves_the_others_and_a_new_one_is_appended():
    text = "intro\n<!-- results:a -->\nold a\n<!-- /results:a -->\nmiddle\n<!-- results:b -->\nold b\n<!-- /results:b -->\n"
    new = splice(text, {"b": "<!-- results:b -->\nnew b\n<!-- /results:b -->"})
    assert new == text.replace("old b", "new b")
    grown = splice(new, {"c": "<!-- results:c -->\nc\n<!-- /results:c -->"}, required=False)
    assert grown.startswith(new.rstrip("\n")) and grown.endswith("<!-- results:c -->\nc\n<!-- /results:c -->\n")
    with pytest.raises(ValueError, match="results:c"):
        splice(new, {"c": "x"})


def test_the_storm_table_compares_the_feed_on_with_the_feed_off_and_names_the_training_storms():
    names = [name for name, _ in STORM_VARIANTS]
    assert names == ["feed on", "feed off", "zero delay"]
    storms = ["halloween2003", "march2011"]
    text = storm_table([("May 2024", dict(zip(names, (_cell(11.0, storms), _cell(10.0, []), _cell(12.5, storms)))))], 50)
    (row,) = [line for line in text.splitlines() if line.startswith("| May 2024")]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells == ["May 2024", "halloween2003, march2011 (57, 0.5)", "11.00", "22.00", "94 %", "92 %", "10.00",
                     "20.00", "94 %", "+10%", "12.50", "50/50/50"]
    assert "seeds 1000-1049" in text


def test_a_storm_cell_counts_only_the_runs_of_its_own_sweep(tmp_path, shared_data):
    """A store folder keeps runs flown with other code or parameters beside the current ones (a new
    registry entry changes every run's key): the cell's figures come from this sweep's runs alone."""
    from pathlib import Path

    from fcmpc.montecarlo.results import run_storm
    from fcmpc.montecarlo.store import RunStore

    root = Path(__file__).resolve().parents[1]
    feed_off = dict(STORM_VARIANTS)["feed off"]
    first = run_storm("march2011", feed_off, 2, tmp_path, root)
    (runs,) = tmp_path.glob("storms/*/march2011_real/sweep/runs")
    stale = dict(RunStore(runs).read().to_pylist()[0], run_key="flown-by-older-code", remaining_km=1e4)
    RunStore(runs).append([stale])
    again = run_storm("march2011", feed_off, 2, tmp_path, root)
    assert first["runs"] == again["runs"] == 2
    assert again["median_km"] == first["median_km"] < 1e3
    # the prediction made before flying, from the runs' own navigator settings, as the other tables' rows
    from companion.params import validate_all
    from fcmpc.montecarlo.cli_table import route_prediction
    from sitl.scenario import load_scenario

    scenario = load_scenario("march2011_real")
    stored = RunStore(runs).read().to_pylist()[0]
    told = route_prediction(scenario, validate_all({**scenario.nav_overrides(), "FUS_SYMH_K": stored["FUS_SYMH_K"],
                                                    "FUS_BQA_N": stored["FUS_BQA_N"]})).arrival_r95_m / 1e3
    assert first["pred_r95_km"] == pytest.approx(told, rel=1e-9) and 0.0 <= first["pred95_pct"] <= 100.0

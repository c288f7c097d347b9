"""Fit on some storms, judge on others (issue 46, item 4): fcmpc-fit-storms writes the storm-time
parameters of named storms with a header naming them; fcmpc-montecarlo refuses to score a storm with
parameters fitted on it and records the training storms; no scenario carries storm-time values."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.params import read_parm_file
from fcmpc.montecarlo.fit_storms import (STORM_PARAMS, OwnStormError, check_held_out, fitted_on, leave_one_out, main,
                                   parm_name, pool)
from fcmpc.montecarlo.cli import main as montecarlo_main
from sitl.scenario import SCENARIO_DIR, load_scenario
from sitl.storms.events import storm_events
from sitl.world.build import storm_component_correlations, storm_component_walks


@pytest.fixture(scope="module")
def stpatrick_parm(tmp_path_factory, shared_data):
    """fcmpc-fit-storms --train stpatrick2015: the file and what it holds."""
    path = tmp_path_factory.mktemp("fit") / "stpatrick.parm"
    assert main(["--train", "stpatrick2015", "--out", str(path), "--data-dir", str(shared_data)]) == 0
    return path


def test_one_storms_fit_is_its_scenarios_own_walks_and_names_it(stpatrick_parm, shared_data):
    """Trained on one storm, the file holds that storm's walks, correlation times and correlations
    along its scenario's route (storm_component_walks / _correlations, the north residual with the
    ring current at FUS_SYMH_K 1 removed), to the 0.1 and 0.01 they are written with, every
    storm-time parameter of the list, and a header naming the storm."""
    scenario = load_scenario("stpatrick2015_real")
    values = read_parm_file(stpatrick_parm)
    assert set(values) == set(STORM_PARAMS)
    assert fitted_on(stpatrick_parm) == ("stpatrick2015",)
    q, tau = storm_component_walks(scenario, shared_data)
    q_res, tau_res = storm_component_walks(scenario, shared_data, symh_ratio=1.0)
    rho = storm_component_correlations(scenario, shared_data)
    rho_res = storm_component_correlations(scenario, shared_data, symh_ratio=1.0)
    assert [values[f"FUS_BQA_{c}"] for c in "NEZ"] == pytest.approx(q, abs=0.051)
    assert [values[f"FUS_BQA_T{c}"] for c in "NEZ"] == pytest.approx(tau, abs=0.0051)
    assert [values[f"FUS_BQA_R{p}"] for p in ("NE", "NZ", "EZ")] == pytest.approx(rho, abs=0.0051)
    assert values["FUS_SYMH_N"] == pytest.approx(q_res[0], abs=0.051)
    assert values["FUS_SYMH_TN"] == pytest.approx(tau_res[0], abs=0.0051)
    assert [values["FUS_SYMH_RNE"], values["FUS_SYMH_RNZ"]] == pytest.approx(rho_res[:2], abs=0.0051)


def test_storms_pool_variance_rates_median_times_and_mean_correlations():
    """Rates pool as the root mean square, correlation times as the median with a random walk (0)
    infinitely long, correlations as the mean."""
    fits = [{"FUS_BQA_N": 10.0, "FUS_BQA_TE": 0.0, "FUS_SYMH_TN": 1.0, "FUS_BQA_REZ": -0.5},
            {"FUS_BQA_N": 20.0, "FUS_BQA_TE": 2.0, "FUS_SYMH_TN": 3.0, "FUS_BQA_REZ": 0.1},
            {"FUS_BQA_N": 50.0, "FUS_BQA_TE": 0.0, "FUS_SYMH_TN": 0.0, "FUS_BQA_REZ": 0.1}]
    assert pool(fits) == {"FUS_BQA_N": 31.6, "FUS_BQA_TE": 0.0, "FUS_SYMH_TN": 3.0, "FUS_BQA_REZ": -0.1}


def test_leave_one_out_trains_on_every_other_storm_of_the_library():
    names = {event.name for event in storm_events()}
    assert len(names) >= 4
    for name in names:
        assert set(leave_one_out(name)) == names - {name}


def test_a_storm_is_never_scored_with_parameters_fitted_on_it(stpatrick_parm, shared_data, capsys):
    """The Monte Carlo refuses, before flying and with a message naming the storm, a storm world
    scored with a .parm fitted on its storm, with --storm-params naming it, or with the registry's
    storm defaults (fitted on may2024) on May 2024; a storm among others in a file is refused as well."""
    common = ["--runs", "1", "--controllers", "fc", "--no-plots", "--quiet", "--data-dir", str(shared_data)]
    refused = [["--scenario", "stpatrick2015_real", "--params", str(stpatrick_parm)],
               ["--scenario", "march2011_real", "--storm-params", "march2011,halloween2003"],
               ["--scenario", "may2024_real", "--storm-params", "registry"],
               ["--scenario", "paper_long_storm", "--storm-params", "registry"]]
    for argv in refused:
        assert montecarlo_main([*argv, *common]) == 2, argv
        err = capsys.readouterr().err
        assert "fitted on" in err and "--storm-params loo" in err, (argv, err)
    with pytest.raises(OwnStormError, match="halloween2003"):
        check_held_out(load_scenario("halloween2003_real"), ("may2024", "halloween2003"))
    check_held_out(load_scenario("halloween2003_real"), ("may2024", "march2011"))
    check_held_out(load_scenario("pacific"), ("may2024",))   # no storm: nothing to hold out


def test_a_held_out_storm_is_scored_and_its_summary_names_the_training_storms(stpatrick_parm, shared_data,
                                                                              tmp_path):
    """March 2011 scored with the St Patrick's fit: it flies, its summary.json names the file and
    the storm, and the parameters it flew with are the file's."""
    out = tmp_path / "mc"
    argv = ["--scenario", "march2011_real", "--params", str(stpatrick_parm), "--runs", "1", "--controllers", "fc",
            "--no-plots", "--quiet", "--workers", "1", "--out", str(out), "--data-dir", str(shared_data)]
    assert montecarlo_main(argv) == 0
    summary = json.loads((out / "march2011_real" / "summary.json").read_text())
    assert summary["storm_params"] == {"source": f"--params {stpatrick_parm}", "storms": ["stpatrick2015"]}
    fitted = read_parm_file(stpatrick_parm)
    assert {k: summary["parameters"][k] for k in STORM_PARAMS} == pytest.approx(fitted, abs=1e-6)


def test_no_scenario_carries_storm_time_values():
    """No bundled world declares a storm-time parameter: it would be fitted on its own storm."""
    for path in sorted(SCENARIO_DIR.glob("*.toml")):
        declared = set(load_scenario(path.stem).nav_overrides()) & set(STORM_PARAMS)
        assert not declared, (path.stem, sorted(declared))


@pytest.mark.slow
def test_the_committed_paper_storm_parameters_are_the_fit_without_may2024(shared_data, tmp_path):
    """params/storms-halloween2003+march2011+stpatrick2015.parm (what the tests of the paper's May 2024
    worlds fly with) is what fcmpc-fit-storms --loo may2024 writes today."""
    names = leave_one_out("may2024")
    committed = Path(__file__).resolve().parents[1] / "params" / parm_name(names)
    written = tmp_path / "loo.parm"
    assert main(["--loo", "may2024", "--out", str(written), "--data-dir", str(shared_data)]) == 0
    assert written.read_text() == committed.read_text()
    assert fitted_on(committed) == ("halloween2003", "march2011", "stpatrick2015")


def test_a_fit_by_the_miss_flies_only_the_tuning_seeds():
    """The fit by miss may fly seeds 0-99 only: the judging seeds (1000 on) never set a parameter."""
    from fcmpc.montecarlo.engines import Engine
    from fcmpc.montecarlo.fit_miss import fit_by_miss

    for seeds in ([1000], [99, 100], []):
        with pytest.raises(ValueError, match="tuning seeds"):
            fit_by_miss([("march2011",)], lambda names, ratio: {}, seeds, Engine("local", 1))


def test_leave_one_out_uses_the_fit_by_miss_and_it_never_names_the_storm_it_scores(shared_data):
    """Every committed fit by miss names its training storms, excludes the storm it is there to score
    (its file name is the other storms'), and is what --storm-params loo gives that storm."""
    from fcmpc.montecarlo.fit_storms import PARAMS_DIR, storm_params_for

    for event in storm_events():
        names = leave_one_out(event.name)
        committed = PARAMS_DIR / parm_name(names, by_miss=True)
        if not committed.is_file():
            continue
        assert fitted_on(committed) == names and event.name not in names
        values, used = storm_params_for(load_scenario(f"{event.name}_real"), "loo", shared_data)
        assert used == names and values == read_parm_file(committed)
        assert "FUS_SYMH_K" in values and set(STORM_PARAMS) <= set(values)
        with pytest.raises(OwnStormError, match=event.name):
            check_held_out(load_scenario(f"{event.name}_real"), (*names, event.name))


@pytest.mark.slow
def test_a_fit_by_miss_on_its_own_store_writes_the_same_parm_and_reads_each_storm_once(shared_data, tmp_path,
                                                                                      monkeypatch):
    """The smallest fit (march2011, seed 0, one candidate: two real in-process runs, feed on and off):
    flown into a store, then again on that store, it writes the same .parm, the second call flying
    nothing (no new part file); each storm's scenario is read once a fit, not once per run."""
    import sitl.scenario
    from fcmpc.montecarlo import fit_miss
    from fcmpc.montecarlo.store import RunStore

    reads = []
    for module in (sitl.scenario, fit_miss):
        real = getattr(module, "load_scenario", sitl.scenario.load_scenario)
        monkeypatch.setattr(module, "load_scenario", lambda name, real=real: reads.append(name) or real(name),
                            raising=False)
    store = tmp_path / "store"
    argv = ["--train", "march2011", "--by-miss", "--seeds", "1", "--scales", "1", "--ratios", "0", "--workers", "1",
            "--store", str(store), "--data-dir", str(shared_data)]
    assert main([*argv, "--out", str(tmp_path / "first.parm")]) == 0
    fit_reads = [name for name in reads if name == "march2011_real"]
    parts = RunStore(store / "runs").parts()
    assert len(parts) == 1 and RunStore(store / "runs").read().num_rows == 2
    assert main([*argv, "--out", str(tmp_path / "second.parm")]) == 0
    assert RunStore(store / "runs").parts() == parts
    assert (tmp_path / "second.parm").read_text() == (tmp_path / "first.parm").read_text()
    assert "FUS_SYMH_K" in read_parm_file(tmp_path / "first.parm")
    assert fit_reads == ["march2011_real"]

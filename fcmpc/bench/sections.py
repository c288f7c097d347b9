"""The benchmarks, each part timed beside its anchors: how fast each part runs here
(``fcmpc-bench``, ``scripts/bench.py``; :data:`SECTIONS` in the order they run, :data:`QUICK_SECTIONS`
for ``--quick``).

Each row prints our median, the anchors it is judged against (the README's figure from before
issue 13, measured on a faster machine, and the baseline measured on the 2-core development
machine before the speed work, with the ratio to it: :data:`BASELINE_HERE`) and the target
(issue 13): one MPC update+solve beside the bare OSQP solve of the same problem (the floor:
what the solver itself costs, called through its compiled object, and the time OSQP reports for
it); the field model per point beside pygeomag's per point (the ratio); the geomagnetic fix; one
mission step while cruising; the 50-run x 3-controller Monte Carlo; the simulator's speed-up over real time; the
CPU seconds a simulated hour of mission costs the companion beside pymavlink's floor for parsing the same
messages, and the companion's message capacity (issue 49). Timings are medians of many repetitions of wall time (p99 where a
tail matters); on a machine shared with other work they are indicative only, and the ratios
beside an anchor measured in the same run are the robust figures. Nothing here is asserted by
the tests.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from companion.nav.field import decl_incl_gradient, geomagnetic_fix, load_wmm
from companion.nav.mission import Measurement, Mission
from companion.nav.mpc import MpcController, MpcSettings
from companion.params import NavConfig, validate_all

__all__ = ["BASELINE_HERE", "QUICK_SECTIONS", "Row", "SECTIONS", "bench_companion", "bench_field", "bench_mission_step",
           "bench_montecarlo", "bench_mpc", "bench_simulator", "companion_rows"]

Row = tuple[str, str, str, str]       # benchmark, ours, anchor, target

# Two anchors per row: the README's figures from before issue 13 (measured on a faster machine)
# and the baseline measured on the 2-core development machine on 2026-11-30, idle, before the
# speed work of issue 13 (whose Python runs about 3x slower): judge a change by the ratio to the
# baseline of the machine it runs on.
BASELINE_HERE = {
    "osqp": 210e-6, "wmm_scalar": 77e-6, "gradient": 406e-6, "fix": 2027e-6, "Fc-MPC": 3347e-6,
    "Fc-MPC, fusing every step": 4718e-6, "LTV-MPC": 882e-6, "montecarlo": 54.6, "sitl": 533.0,
}


def _vs(ours_s: float, key: str, unit: str = "us") -> str:
    """``baseline here X: N.Nx faster`` against :data:`BASELINE_HERE` (a time in seconds)."""
    base = BASELINE_HERE[key]
    shown = f"{base * 1e6:.0f} us" if unit == "us" else f"{base:.1f} s" if unit == "s" else f"{base * 1e3:.1f} ms"
    return f"baseline here {shown}: {base / ours_s:.2f}x"


def _time_calls(call: Callable[[], object], repeats: int) -> np.ndarray:
    """Seconds of each of ``repeats`` calls."""
    out = np.empty(repeats)
    for index in range(repeats):
        started = time.perf_counter()
        call()
        out[index] = time.perf_counter() - started
    return out


def _us(samples_s: np.ndarray, tail: bool = False) -> str:
    t = samples_s * 1e6
    return f"{np.median(t):.1f} us" + (f" (p99 {np.percentile(t, 99):.0f})" if tail else "")


def bench_mpc(repeats: int = 5000) -> list[Row]:
    """One update+solve of the Table 4 problem (N = 2) with B varying each call, per backend,
    beside the time the solver itself reports for the same update and solve (OSQP's
    ``info.run_time``: its C code alone, the floor)."""
    rng = np.random.default_rng(0)
    g = np.array([[3.4158e-6, -3.07429e-6], [-7.5221e-7, 1.184975e-5]])  # deg/m at the start point
    b = g * 3600.0 * 360.0 * (50 / 3.6)
    rows: list[Row] = []
    for solver in ("osqp", "daqp"):
        controller = MpcController(MpcSettings(solver=solver))
        states = rng.normal(0.0, 200.0, (repeats, 2))
        scales = 1.0 + 0.01 * rng.normal(size=repeats)
        ours, reported = np.empty(repeats), np.empty(repeats)
        for i in range(repeats):
            started = time.perf_counter()
            solution = controller.solve(b * scales[i], states[i], np.zeros(2))
            ours[i] = time.perf_counter() - started
            reported[i] = solution.solve_time_s
        rows.append((f"MPC update+solve, {solver} (N=2)", _us(ours, tail=True),
                     f"{solver} alone (its reported time) {_us(reported)}; README 59 us; "
                     f"{_vs(float(np.median(ours)), 'osqp')}" if solver == "osqp"
                     else f"{solver} alone (its reported time) {_us(reported)}",
                     "<= 40 us" if solver == "osqp" else "-"))
    return rows


def bench_field(repeats: int = 2000) -> list[Row]:
    """WMM per point (scalar and 10^4-point arrays) beside pygeomag's per point, the gradient,
    and one geomagnetic fix."""
    model = load_wmm("WMM2020")
    rng = np.random.default_rng(1)
    lat, lon = rng.uniform(27, 34, 10_000), rng.uniform(145, 165, 10_000)
    scalar = _time_calls(lambda: model.elements(30.5, 155.0, 0.0, 2024.36), repeats)
    array = _time_calls(lambda: model.elements(lat, lon, 0.0, 2024.36), 30) / len(lat)
    # a new point each call: the model keeps its last few exact evaluations (a step reuses them)
    where = iter(range(10**9))
    grad = _time_calls(lambda: decl_incl_gradient(model, float(lat[next(where) % 10_000]), 155.0, 0.0, 2024.36),
                       repeats // 4)
    truth = model.elements(30.5, 155.0, 0.0, 2024.36)
    fix = _time_calls(lambda: geomagnetic_fix(model, truth.decl_deg, truth.incl_deg, 30.6, 155.1, 0.0, 2024.36),
                      repeats // 4)
    try:
        from pygeomag import GeoMag

        geomag = GeoMag(coefficients_file="wmm/WMM_2020.COF")
        points = iter(range(10**9))
        theirs = _time_calls(lambda: geomag.calculate(glat=float(lat[next(points) % 10_000]), glon=155.0, alt=0.0,
                                                      time=2024.36), repeats)
        anchor = np.median(theirs)
        ratio = (f"pygeomag {_us(theirs)} per point: ours {anchor / np.median(scalar):.1f}x (scalar), "
                 f"{anchor / np.median(array):.0f}x (arrays); README 21 us; "
                 f"{_vs(float(np.median(scalar)), 'wmm_scalar')}")
    except ImportError:
        ratio = "pygeomag not installed"
    return [("WMM2020, one point (scalar path)", _us(scalar), ratio, "-"),
            ("WMM2020, per point in 10^4-point arrays", _us(array), "", "-"),
            ("(D, I) gradient at a point (exact)", _us(grad), f"5-point stencil {_vs(float(np.median(grad)), 'gradient')}",
             "-"),
            ("geomagnetic fix, prior 15 km off", _us(fix), f"README 459 us; {_vs(float(np.median(fix)), 'fix')}", "-")]


def bench_mission_step() -> list[Row]:
    """One Mission.step while cruising, timed inside in-process missions (Fc with and without
    the Kalman fusion, LTV)."""
    from fcmpc.montecarlo.inprocess import fly_in_process
    from sitl.scenario import load_scenario
    from sitl.world.build import build_truth_field

    scenario = load_scenario("paper_pacific")
    truth = build_truth_field(scenario)
    rows: list[Row] = []
    for label, overrides, anchor, target in (
            ("Fc-MPC", {"NAV_CONTROLLER": 2}, "README 862 us (without the filter)", "<= 400 us"),
            ("Fc-MPC, fusing every step", {"NAV_CONTROLLER": 2, "FUS_SIGMA": 10.0}, "README 1032 us", "-"),
            # the work the README's 862 us measured: the paper's estimator (Table 3) on (D, I)
            ("Fc-MPC, the paper's estimator", {"NAV_CONTROLLER": 2, "FUS_MODEL": 1, "NAV_ELEMENTS": 1},
             "README 862 us (this work)", "<= 400 us"),
            ("LTV-MPC", {"NAV_CONTROLLER": 1}, "README 203 us", "-")):
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), **overrides}))
        samples: list[float] = []
        original = Mission.step

        def timed(self: Mission, meas: Measurement, _orig=original, _samples=samples):
            started = time.perf_counter()
            out = _orig(self, meas)
            if out.phase == "cruise":
                _samples.append(time.perf_counter() - started)
            return out

        Mission.step = timed  # type: ignore[method-assign]
        try:
            for seed in range(5):
                fly_in_process(nav, scenario, seed, truth)
        finally:
            Mission.step = original  # type: ignore[method-assign]
        rows.append((f"mission step (cruise), {label}", _us(np.array(samples), tail=True),
                     f"{anchor}; {_vs(float(np.median(samples)), label)}" if label in BASELINE_HERE else anchor,
                     target))
    return rows


def bench_montecarlo() -> list[Row]:
    """Wall seconds of the 50-run, 3-controller Pacific Monte Carlo on all cores (local pool)."""
    from fcmpc.montecarlo.batch import run_montecarlo
    from sitl.scenario import load_scenario

    scenario = load_scenario("paper_pacific")
    values = validate_all(scenario.nav_overrides())
    started = time.perf_counter()
    run_montecarlo("paper_pacific", 50, [0, 1, 2], os.cpu_count() or 1, values, progress=False)
    wall = time.perf_counter() - started
    return [(f"Monte Carlo, 50 runs x 3 controllers ({os.cpu_count()} workers)",
             f"{wall:.1f} s wall", f"README 22-29 s; {_vs(wall, 'montecarlo', 's')}", "<= 10 s")]


def bench_simulator() -> list[Row]:
    """The MAVLink simulator's speed-up over real time and message rate (fcmpc.bench.simulator.benchmark)."""
    from fcmpc.bench.simulator import benchmark

    result = benchmark()
    base = BASELINE_HERE["sitl"]
    return [(f"SITL speed-up over real time ({k})", f"{v}", f"README 1208x; baseline here {base:.0f}x: "
             f"{float(v) / base:.2f}x", ">= 2000x")
            if k.startswith("speed") else (f"SITL {k}", f"{v}", "", "") for k, v in result.items()]


CAPACITY_FIRST_MSGS_PER_S = 55_400.0
"""The companion's capacity as its first version measured it (README, 2026-11-22; issue 49: 24,100 later)."""


def companion_rows(result: dict) -> list[Row]:
    """:func:`fcmpc.bench.companion_process.run`'s numbers as rows: the CPU a simulated hour of mission
    costs the companion beside the floor of parsing the same messages with pymavlink alone, and
    the capacity beside its first version's."""
    rows: list[Row] = []
    if "mission_cpu_s_per_sim_hour" in result:
        rows.append(("companion CPU s per simulated hour of mission (lockstep, the stand-in's stream rates)",
                     f"{result['mission_cpu_s_per_sim_hour']:g} s",
                     f"floor: pymavlink parsing its {result['messages_per_sim_hour']:,} messages alone "
                     f"{result['parse_floor_cpu_s_per_sim_hour']:g} s", "-"))
    for key, value in result.items():
        if key in ("mission_cpu_s_per_sim_hour", "parse_floor_cpu_s_per_sim_hour", "messages_per_sim_hour"):
            continue
        if key == "capacity_msgs_per_s":
            rows.append((f"companion {key}", f"{value}",
                         "the FC's messages through the link (parse, tlog) and the receive hook, with the outputs they "
                         "trigger, per CPU s of the receiving thread (the prediction's apart), median of the replays; "
                         f"first version {CAPACITY_FIRST_MSGS_PER_S:,.0f} (README); "
                         f"{float(value) / CAPACITY_FIRST_MSGS_PER_S:.2f}x", ">= 55,000"))
        elif key == "capacity_spread_msgs_per_s":
            rows.append(("companion capacity: slowest and fastest replay", f"{value[0]}-{value[1]}", "", ""))
        elif key == "capacity_parse_floor_msgs_per_s":
            rows.append((f"companion {key}", f"{value}", "pymavlink's parse_buffer alone on the same datagrams, per "
                         "CPU s: the ceiling no companion on pymavlink passes", ""))
        elif key == "capacity_other_threads_cpu_s":
            rows.append(("companion: its other thread's CPU meanwhile (the route's prediction, once)", f"{value:g} s",
                         "", ""))
        else:
            rows.append((f"companion {key}", f"{value}", "", ""))
    return rows


def bench_companion() -> list[Row]:
    """The CPU a simulated hour of mission costs the companion, its sustained input rate and its
    capacity against the simulator (:mod:`fcmpc.bench.companion_process`)."""
    from fcmpc.bench.companion_process import run

    return companion_rows(run())


# the parts in the order they run; --quick runs the first three
QUICK_SECTIONS: tuple[Callable[[], list[Row]], ...] = (bench_mpc, bench_field, bench_mission_step)
SECTIONS: tuple[Callable[[], list[Row]], ...] = QUICK_SECTIONS + (bench_montecarlo, bench_simulator, bench_companion)

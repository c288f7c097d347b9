"""Benchmarks, printed as a table of medians: how fast each part runs on this machine.

    fcmpc-bench                 # everything (about 2 minutes on 2 cores)
    fcmpc-bench --quick         # skip the 150-mission Monte Carlo and the closed-loop parts

Rows: one MPC update+solve (OSQP and daqp), the field model per point, the geomagnetic fix,
one full mission step (field, gradient, QP, fusion), the 50-run x 3-controller Monte Carlo
wall time, the simulator's speed-up over real time and message rate, and the companion's
control-step latency while it handles the simulator's streams. Timings are medians of many
repetitions (p99 where a tail matters); nothing here is asserted by the tests.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys
import time
from typing import Callable

import numpy as np

from companion.cli import ArgumentParser, run_main
from companion.nav.field import decl_incl_gradient, geomagnetic_fix, load_wmm
from companion.nav.mission import Measurement, Mission
from companion.nav.mpc import MpcController, MpcSettings
from companion.params import NavConfig, validate_all


def _time_calls(call: Callable[[], object], repeats: int) -> np.ndarray:
    """Seconds of each of ``repeats`` calls."""
    out = np.empty(repeats)
    for index in range(repeats):
        started = time.perf_counter()
        call()
        out[index] = time.perf_counter() - started
    return out


def bench_mpc(repeats: int = 5000) -> list[tuple[str, str]]:
    """One update+solve of the Table 4 problem (N = 2) with B varying each call, per backend."""
    rng = np.random.default_rng(0)
    g = np.array([[3.4158e-6, -3.07429e-6], [-7.5221e-7, 1.184975e-5]])  # deg/m at the start point
    b = g * 3600.0 * 360.0 * (50 / 3.6)
    rows = []
    for solver in ("osqp", "daqp"):
        controller = MpcController(MpcSettings(solver=solver))
        states = rng.normal(0.0, 200.0, (repeats, 2))
        scales = 1.0 + 0.01 * rng.normal(size=repeats)
        index = iter(range(repeats))

        def call() -> None:
            i = next(index)
            controller.solve(b * scales[i], states[i], np.zeros(2))

        t = _time_calls(call, repeats) * 1e6
        rows.append((f"MPC update+solve, {solver} (N=2)", f"{np.median(t):.1f} us  (p99 {np.percentile(t, 99):.1f})"))
    return rows


def bench_field(repeats: int = 2000) -> list[tuple[str, str]]:
    """WMM per point (scalar and 10^4-point arrays), the gradient, and one geomagnetic fix."""
    model = load_wmm("WMM2020")
    rng = np.random.default_rng(1)
    lat, lon = rng.uniform(27, 34, 10_000), rng.uniform(145, 165, 10_000)
    scalar = _time_calls(lambda: model.elements(30.5, 155.0, 0.0, 2024.36), repeats) * 1e6
    array = _time_calls(lambda: model.elements(lat, lon, 0.0, 2024.36), 30) / len(lat) * 1e6
    grad = _time_calls(lambda: decl_incl_gradient(model, 30.5, 155.0, 0.0, 2024.36), repeats // 4) * 1e6
    truth = model.elements(30.5, 155.0, 0.0, 2024.36)
    fix = _time_calls(lambda: geomagnetic_fix(model, truth.decl_deg, truth.incl_deg, 30.6, 155.1, 0.0, 2024.36),
                      repeats // 4) * 1e6
    return [("WMM2020, one point (scalar path)", f"{np.median(scalar):.1f} us"),
            ("WMM2020, per point in 10^4-point arrays", f"{np.median(array):.2f} us"),
            ("(D, I) gradient at a point", f"{np.median(grad):.1f} us"),
            ("geomagnetic fix, prior 15 km off", f"{np.median(fix):.1f} us")]


def bench_mission_step() -> list[tuple[str, str]]:
    """One Mission.step while cruising, timed inside in-process missions (Fc with and without
    the Kalman fusion, LTV)."""
    from sitl.inprocess import fly_in_process
    from sitl.scenario import load_scenario
    from sitl.world.build import build_truth_field

    scenario = load_scenario("pacific")
    truth = build_truth_field(scenario)
    rows = []
    for label, overrides in (("Fc-MPC", {"NAV_CONTROLLER": 2}),
                             ("Fc-MPC, fusing every step", {"NAV_CONTROLLER": 2, "FUS_SIGMA": 10.0}),
                             ("LTV-MPC", {"NAV_CONTROLLER": 1})):
        nav = NavConfig.from_values(validate_all({**scenario.nav_overrides(), **overrides}))
        samples: list[float] = []
        original = Mission.step

        def timed(self: Mission, meas: Measurement, _orig=original):
            started = time.perf_counter()
            out = _orig(self, meas)
            if out.phase == "cruise":
                samples.append(time.perf_counter() - started)
            return out

        Mission.step = timed  # type: ignore[method-assign]
        try:
            for seed in range(5):
                fly_in_process(nav, scenario, seed, truth)
        finally:
            Mission.step = original  # type: ignore[method-assign]
        t = np.array(samples) * 1e6
        rows.append((f"mission step (cruise), {label}", f"{np.median(t):.0f} us  (p99 {np.percentile(t, 99):.0f})"))
    return rows


def bench_montecarlo() -> list[tuple[str, str]]:
    """Wall seconds of the 50-run, 3-controller Pacific Monte Carlo on all cores."""
    from montecarlo.batch import run_montecarlo
    from sitl.scenario import load_scenario

    scenario = load_scenario("pacific")
    values = validate_all(scenario.nav_overrides())
    started = time.perf_counter()
    run_montecarlo("pacific", 50, [0, 1, 2], os.cpu_count() or 1, values, progress=False)
    return [(f"Monte Carlo, 50 runs x 3 controllers ({os.cpu_count()} workers)",
             f"{time.perf_counter() - started:.1f} s wall")]


def bench_simulator() -> list[tuple[str, str]]:
    """The MAVLink simulator's speed-up over real time and message rate (sitl.server.benchmark)."""
    from sitl.server import benchmark

    result = benchmark()
    return [(f"SITL speed-up over real time ({k})" if k.startswith("speed") else f"SITL {k}", f"{v}")
            for k, v in result.items()]


def bench_companion() -> list[tuple[str, str]]:
    """The companion's control-step latency and sustained input rate against the simulator."""
    from companion.app import benchmark

    return [(f"companion {k}", f"{v}") for k, v in benchmark().items()]


def _run(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog="fcmpc-bench", description="fcmpc benchmarks (medians)")
    parser.add_argument("--quick", action="store_true", help="skip the Monte Carlo and the closed-loop parts")
    args = parser.parse_args(argv)
    sections: list[Callable[[], list[tuple[str, str]]]] = [bench_mpc, bench_field, bench_mission_step]
    if not args.quick:
        sections += [bench_montecarlo, bench_simulator, bench_companion]
    rows: list[tuple[str, str]] = []
    for section in sections:
        try:
            rows += section()
        except Exception as err:  # a missing part must not hide the others' numbers
            rows.append((section.__name__, f"FAILED: {type(err).__name__}: {err}"))
        print(f"  ... {section.__name__} done", file=sys.stderr)
    width = max(len(name) for name, _ in rows) + 2
    print(f"\n{'benchmark':<{width}}median")
    print("-" * (width + 30))
    for name, value in rows:
        print(f"{name:<{width}}{value}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-bench", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())

"""Shared test setup: the slow marker and the location of the read-only real data."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

os.environ.setdefault("MAVLINK20", "1")
# Tiny matrices everywhere: BLAS threads only slow them (the INS step goes from 65 us to ms).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("FCMPC_DATA_DIR", REPO_ROOT.parent / "shared" / "data"))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--run-slow", action="store_true", help="also run tests marked slow")


# The longest modules go first: PX4's GPS-lost flight (paced in wall time, 419-428 s), the full Pacific
# mission closed loop (CPU-bound, 153 s on 2026-12-02, 641 s on the 3-4x slower machine of 2026-12-03;
# it runs at a lower priority, so it fills what the wall-paced firmware leaves), the PX4 module (its
# quadrant cases with the 30 s start-up), the ArduPilot module, the storm missions; then the other
# slow ones: parallel workers (pytest-xdist, one module at a time) take modules in this order, so the
# long ones start at once instead of last on a worker while the others idle. xdist's loadscope would
# reorder modules by their number of tests (most first, so these single-test modules last): setup.cfg
# turns that off with --no-loadscope-reorder.
LONGEST_MODULES = ("test_px4_gps_lost.py", "test_missions_slow.py", "test_px4.py", "test_ardupilot.py",
                   "test_storm_missions_slow.py")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker more than cores (at most 4, setup.cfg). The firmware tests spend most of
    their wall time waiting on SITL paced in wall time (PX4 at 4-5x, ArduPilot at 10x): in a CI run with
    one worker per core, 2 cores were busy 1.3 of 2 on average."""
    return min(4, (os.cpu_count() or 1) + 1)


def _start_order(item: pytest.Item) -> int:
    if item.path.name in LONGEST_MODULES:
        return LONGEST_MODULES.index(item.path.name)
    return len(LONGEST_MODULES) + (0 if "slow" in item.keywords else 1)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # whole modules move (a module fixture is set up once), in collection order within each class
    module_order: dict = {}
    for item in items:
        module_order[item.path] = min(module_order.get(item.path, len(LONGEST_MODULES) + 1), _start_order(item))
    items.sort(key=lambda item: module_order[item.path])
    # CI runs the same command as a developer; CI=true switches the slow cases on.
    if config.getoption("--run-slow") or os.environ.get("CI", "").lower() == "true":
        return
    skip = pytest.mark.skip(reason="slow: runs in CI (CI=true) or with --run-slow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The read-only real data folder (../shared/data); tests needing it skip when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder not found at {SHARED_DATA} (set FCMPC_DATA_DIR)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def log171(shared_data: Path) -> Path:
    """The real ArduPilot DataFlash log ../shared/data/logs/log171.bin."""
    path = shared_data / "logs" / "log171.bin"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


LOG171_TYPES = ("MAG", "MAG2", "MAG3", "IMU", "IMU2", "IMU3", "ATT", "GPS")


@pytest.fixture(scope="session")
def log171_reference(log171: Path) -> dict:
    """Counts, first/last times per type, the first MAG and the first 3D GPS fix of log171.bin,
    read with a plain pymavlink loop: the independent reference the replay code is checked against."""
    from collections import Counter

    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(log171))
    counts: Counter = Counter()
    first: dict[str, float] = {}
    last: dict[str, float] = {}
    mag0 = gps0 = None
    try:
        while (msg := conn.recv_match(type=list(LOG171_TYPES))) is not None:
            mtype = msg.get_type()
            t = (msg.T if mtype == "GPS" else msg.TimeMS) / 1000.0  # Copter 3.3: GPS TimeMS is GPS time of week
            counts[mtype] += 1
            first.setdefault(mtype, t)
            last[mtype] = t
            if mtype == "MAG" and mag0 is None:
                mag0 = (msg.MagX, msg.MagY, msg.MagZ)
            if mtype == "GPS" and msg.Status >= 3 and gps0 is None:
                gps0 = (msg.Lat, msg.Lng, msg.Alt)
    finally:
        conn.close()
    return {"counts": counts, "first": first, "last": last, "mag0": mag0, "gps0": gps0}


# Property tests run hypothesis's default example count in CI; `--hypothesis-profile=long` runs the
# navigator's fuzz for its target of 10^5 examples (issue 47; FCMPC_LONG_EXAMPLES: another count,
# e.g. half in each of two processes with different --hypothesis-seed).
settings.register_profile("long", max_examples=int(os.environ.get("FCMPC_LONG_EXAMPLES", "100000")), deadline=None,
                          suppress_health_check=list(HealthCheck))

"""The paper's storm missions closed loop via fcmpc_fly (slow: CI only), against the in-process Monte Carlo.

Pass as for the Pacific mission (``test_missions_slow.py``). The short storm is flown in
``test_short_storm_mission_slow.py``: one mission per module, so parallel workers fly them side
by side. The simulator's storm clock is its time since boot, which includes the companion's stationary start-up (one control period, 0.6 % of
the compressed window), so the storm is seen slightly earlier along the track than in-process.
"""
from __future__ import annotations

import pytest

from fcmpc_fly import FlyOptions, fly
from tests.companion.test_closed_loop import assert_close_to_monte_carlo
from tests.companion.test_missions_slow import HANG_S

pytestmark = pytest.mark.timeout(HANG_S + 300.0)


def fly_storm_and_compare(tmp_path, shared_data, scenario: str) -> None:
    """Fly the bundled storm scenario closed loop (seed 0) and check it against the in-process run."""
    if not (shared_data / "storms").is_dir():
        pytest.skip(f"storm data not found under {shared_data}")
    result = fly(FlyOptions(scenario=scenario, seed=0, compare=True, out_dir=str(tmp_path / "run"),
                            timeout_s=HANG_S, tlog=False, data_dir=str(shared_data)))
    assert_close_to_monte_carlo(result)


@pytest.mark.slow
def test_long_storm_mission(tmp_path, shared_data):
    fly_storm_and_compare(tmp_path, shared_data, "long_storm")

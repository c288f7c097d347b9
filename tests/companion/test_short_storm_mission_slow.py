"""The paper's short storm mission closed loop (slow: CI only); a module of its own so a parallel
worker flies it beside the long storm and the Pacific missions; the first 300 km of the route (see ``test_storm_missions_slow.py``)."""
from __future__ import annotations

import pytest

from tests.companion.test_missions_slow import HANG_S
from tests.companion.test_storm_missions_slow import fly_storm_and_compare

pytestmark = pytest.mark.timeout(HANG_S + 300.0)


@pytest.mark.slow
def test_short_storm_mission(tmp_path, shared_data):
    fly_storm_and_compare(tmp_path, shared_data, "short_storm")

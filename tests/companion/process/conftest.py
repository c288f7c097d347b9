"""The ``rig`` fixture: a companion armed in GUIDED and running, and the FC's socket (see rig.py)."""
from __future__ import annotations

import pytest

from tests.companion.process.rig import make_rig


@pytest.fixture
def rig(tmp_path):
    app, fc = make_rig(tmp_path)
    yield app, fc
    app.close()
    fc.close()

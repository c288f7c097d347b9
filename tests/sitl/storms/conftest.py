"""Fixtures of the storm tests: the real observatory records and their disturbance field, read once."""
from __future__ import annotations

from pathlib import Path

import pytest

from sitl import storms as S
from tests.sitl.storms.storm_data import INTERMAGNET


@pytest.fixture(scope="session")
def imag_dir(shared_data: Path) -> Path:
    return shared_data.joinpath(*INTERMAGNET)


@pytest.fixture(scope="session")
def records(shared_data: Path) -> dict[str, S.IagaRecord]:
    return S.load_stations(shared_data)


@pytest.fixture(scope="session")
def disturbance(records) -> S.StormDisturbance:
    return S.StormDisturbance.from_records(records)

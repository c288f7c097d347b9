"""The real crust (EMM2017 degrees 16-790) of the realistic worlds: the pyshtools synthesis on a
route's grid against an independent direct sum at points, the cache, and routes in the south
and on the equator (across the antimeridian) building their truth."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sitl.scenario import load_scenario
from sitl.world import emm
from sitl.world.build import build_truth_field
from sitl.world.emm import crust_grid_for_route, default_emm_file, read_emm, route_box
from tests.sitl.crust_direct import direct_ned_nt

pytestmark = pytest.mark.skipif(not default_emm_file().exists(), reason="EMM2017.COF not in the real data folder")

LOW = 150   # degree of the quick grids: same code path, a fraction of a second to synthesise


@pytest.fixture(scope="module")
def gh():
    epoch, coefficients = read_emm(default_emm_file())
    assert epoch == 2017.0 and coefficients.shape == (2, 791, 791)
    return coefficients


@pytest.mark.slow
def test_full_crust_on_the_pacific_route_matches_a_direct_sum(gh):
    """Degrees 16-790 (the realistic default, through the shared cache) at four points of the
    route against the direct sum: under 1 nT per component (measured 0.12 nT at most)."""
    truth = build_truth_field(load_scenario("pacific_real"))
    for lat, lon in [(33.0, 152.0), (30.7, 155.1), (28.0, 158.0), (31.46, 157.51)]:
        direct = direct_ned_nt(gh, 16, 790, lat, lon)
        assert np.abs(truth.crust_ned_nt(lat, lon, 0.0) - direct).max() < 1.0
    rms = np.sqrt(np.mean(truth.crust.values ** 2, axis=(0, 1)))
    assert np.all((rms > 10.0) & (rms < 300.0))   # measured about 40-90 nT: the crust of the NW Pacific


@pytest.mark.parametrize("start, destination", [((-40.0, 160.0), (-36.0, 168.0)),    # Tasman Sea, south
                                                ((-2.0, 178.0), (3.0, -176.0))])     # equator, across 180
def test_southern_and_equatorial_routes_build_their_crust(tmp_path, gh, start, destination):
    grid = crust_grid_for_route(start, destination, 0.0, min_degree=16, max_degree=LOW, cache=tmp_path)
    middle = ((start[0] + destination[0]) / 2, start[1] + ((destination[1] - start[1] + 180.0) % 360.0 - 180.0) / 2)
    for lat, lon in [start, destination, middle]:
        # within 1 nT per component: measured 0.43 nT at most (the bicubic spline between nodes a
        # quarter of the shortest wavelength apart), of a field of tens of nT
        assert np.abs(grid.ned_nt(lat, lon) - direct_ned_nt(gh, 16, LOW, lat, lon)).max() < 1.0
    with pytest.raises(ValueError, match="leaves the crust grid"):
        grid.ned_nt(start[0] + 25.0, start[1])


def test_route_box_unwraps_the_antimeridian():
    assert route_box((-2.0, 178.0), (3.0, -176.0), 1.0) == ((-3.0, 4.0), (177.0, 185.0))
    assert route_box((33.0, 152.0), (28.0, 158.0)) == ((18.0, 43.0), (142.0, 168.0))


def test_the_second_run_loads_the_grid_from_the_cache(tmp_path, monkeypatch, gh):
    first = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, min_degree=16, max_degree=60, cache=tmp_path)
    files = list(tmp_path.glob("crust_*.npz"))
    assert len(files) == 1 and "n16-60" in files[0].name and "lat18_43_lon142_168" in files[0].name

    def no_synthesis(*args, **kwargs):
        raise AssertionError("synthesised again")
    monkeypatch.setattr(emm, "synthesise_crust_grid", no_synthesis)
    again = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, min_degree=16, max_degree=60, cache=tmp_path)
    assert np.array_equal(again.values, first.values) and np.array_equal(again.lat_deg, first.lat_deg)
    with pytest.raises(AssertionError, match="synthesised again"):   # another degree range is another grid
        crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, min_degree=16, max_degree=61, cache=tmp_path)


def test_a_changed_coefficient_file_is_another_grid(tmp_path):
    copy = tmp_path / "EMM.COF"
    lines = default_emm_file().read_text().splitlines()[:1 + 40 * 41 // 2 + 40]   # header, degrees 1-40
    copy.write_text("\n".join(lines) + "\n")
    one = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, path=copy, min_degree=16, max_degree=30,
                               cache=tmp_path / "cache")
    lines[200] = lines[200][:-1] + ("1" if lines[200][-1] != "1" else "2")   # one coefficient's last digit
    copy.write_text("\n".join(lines) + "\n")
    two = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, path=copy, min_degree=16, max_degree=30,
                               cache=tmp_path / "cache")
    assert len(list((tmp_path / "cache").glob("crust_*.npz"))) == 2 and not np.array_equal(one.values, two.values)


def test_a_missing_coefficient_file_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="FCMPC_DATA_DIR"):
        crust_grid_for_route((33.0, 152.0), (28.0, 158.0), path=tmp_path / "none.COF", cache=tmp_path)


def test_the_crust_grid_refuses_another_altitude(tmp_path):
    grid = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, min_degree=16, max_degree=60, cache=tmp_path)
    assert grid.ned_nt(30.0, 155.0, 99.0).shape == (3,)
    with pytest.raises(ValueError, match="at 0 m"):
        grid.ned_nt(30.0, 155.0, 5000.0)


def test_route_anomaly_is_the_crust_and_what_the_map_misses(tmp_path):
    from companion.nav.field import load_wmm
    from sitl.world.anomaly import plot_crust_anomaly, route_anomaly

    ideal = build_truth_field(load_scenario("paper_pacific"))     # the map is the territory: nothing to see
    none = route_anomaly(ideal, (33.0, 152.0), (28.0, 158.0), 0.0, load_wmm("WMM2020"), points=20)
    assert np.all(none.crust == 0.0) and np.allclose(none.map_error, 0.0, atol=1e-9)
    grid = crust_grid_for_route((33.0, 152.0), (28.0, 158.0), 0.0, min_degree=16, max_degree=60, cache=tmp_path)
    real = route_anomaly(replace(ideal, crust=grid), (33.0, 152.0), (28.0, 158.0), 0.0, load_wmm("WMM2020"), 20)
    assert real.distance_km[-1] == pytest.approx(799.2, abs=1.0)
    assert np.allclose(real.crust, real.map_error)           # the truth's main field is the map's here
    assert 1.0 < np.abs(real.crust[:, 0]).max() < 300.0      # dF of the long-wavelength crust, nT
    assert plot_crust_anomaly(tmp_path / "a.png", real).stat().st_size > 10_000

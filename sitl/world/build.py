"""Build the true field of a scenario: one function for the Monte Carlo and the MAVLink simulator.

:func:`build_truth_field` turns a :class:`~sitl.scenario.Scenario` into a
:class:`~sitl.world.magnetic.TruthField`: the main field of ``[field] main`` (the World
Magnetic Model of the scenario's date, :func:`companion.nav.field.model_for_date`, the
navigator's own model; IGRF-14, :func:`sitl.world.igrf.igrf14_model`; or ArduPilot's own tables,
:mod:`sitl.world.fc_tables`), the real crust of ``[field] crust = "emm2017"`` on the route's
grid (:func:`sitl.world.emm.crust_grid_for_route`, cached), the seeded anomaly field when
``[field] crustal = true`` (drawn for ``seed``; the Monte Carlo redraws it per run with
:meth:`TruthField.for_seed`), plus, when ``[storm] enabled``, the storm disturbance of
:mod:`sitl.storms` with the scenario's time rule:

``utc``
    storm time = scenario ``start_utc`` + mission elapsed seconds (real time).
``compress``
    the storm window is spread linearly over ``expected_duration_s`` of mission time (the
    paper's use). Without an explicit value the expected duration is the geodesic length of
    the mission divided by the companion's default cruise speed (``NAV_SPEED_KMH``).

The storm is a row of the storm library (``[storm] event``, :mod:`sitl.storms.events`: its
stations, reader and index sources). With it comes its space-weather feed: Kp and the ring-current
index (SYM-H where published, else RC) *as published* (:mod:`sitl.storms.published`): at a storm
time, the quick-look value of the last interval published by then, after the ``[storm]`` delays,
with quick-look errors drawn for ``seed`` (:meth:`TruthField.for_seed` redraws them per run), what a
service would give the vehicle (:meth:`TruthField.kp`, :meth:`TruthField.symh`); without an index
file there is no feed. A world without a storm feeds a
quiet day's indices (Kp 0, SYM-H 0 nT, :func:`sitl.world.magnetic.quiet_index`), and
``[storm] kp_feed`` / ``symh_feed`` false withhold either. :func:`storm_component_walks` is how
fast the disturbance moves along the route: what the navigator's storm walks are fitted from, on
other storms than the one it is scored on (``fcmpc-fit-storms``, docs/storms.md).

Mission elapsed seconds are the simulator's time since boot. Past the end of the storm
data the disturbance holds its last value (``outside="hold"``), so a mission that runs
longer than expected keeps a finite field instead of stopping the simulator.
"""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from companion.nav.field import model_for_date
from companion.nav.geo import geodesic_distance_m
from companion.params import SPEC_BY_NAME
from sitl.scenario import Scenario
from sitl.storms import default_data_dir
from sitl.world.emm import EMM_FILE, crust_grid_for_route
from sitl.world.fc_tables import ardupilot_tables
from sitl.world.igrf import igrf14_model
from sitl.world.magnetic import TruthField, quiet_index

__all__ = ["StormUnavailableError", "build_truth_field", "crust_grid", "expected_mission_duration_s", "main_field_model",
           "storm_component_correlations", "storm_component_walks"]


class StormUnavailableError(RuntimeError):
    """The scenario asks for a storm but its data or the storm module cannot be loaded."""


def expected_mission_duration_s(scenario: Scenario, speed_mps: float | None = None) -> float:
    """Geodesic start-to-destination length over the cruise speed (default ``NAV_SPEED_KMH``).

    >>> from sitl.scenario import load_scenario
    >>> round(expected_mission_duration_s(load_scenario("pacific")) / 3600.0, 2)  # 799 km at 50 km/h
    15.98
    """
    if speed_mps is None:
        speed_mps = float(SPEC_BY_NAME["NAV_SPEED_KMH"].default) / 3.6
    if not speed_mps > 0.0:
        raise ValueError(f"cruise speed must be > 0 m/s, got {speed_mps}")
    distance = geodesic_distance_m(scenario.start_lat_deg, scenario.start_lon_deg,
                                   scenario.dest_lat_deg, scenario.dest_lon_deg)
    return distance / speed_mps


def main_field_model(scenario: Scenario):
    """The truth's main-field model of ``[field] main``: WMM of the scenario's date, IGRF-14, or
    ArduPilot's tables (:mod:`sitl.world.fc_tables`)."""
    main = scenario.field_model.main
    if main == "igrf14":
        return igrf14_model(scenario.year)
    if main == "ardupilot":
        return ardupilot_tables()
    return model_for_date(scenario.year)


def crust_grid(scenario: Scenario, data_dir: str | os.PathLike[str] | None = None):
    """The scenario's real crust on its route's grid (``[field] crust``), or None without one.
    ``data_dir`` holds ``crust/EMM2017.COF`` (default :func:`default_data_dir`)."""
    field = scenario.field_model
    if field.crust == "none":
        return None
    folder = Path(data_dir) if data_dir is not None else default_data_dir()
    return crust_grid_for_route((scenario.start_lat_deg, scenario.start_lon_deg),
                                (scenario.dest_lat_deg, scenario.dest_lon_deg), scenario.alt_m,
                                folder / EMM_FILE, field.crust_min_degree, field.crust_max_degree)


def build_truth_field(scenario: Scenario, data_dir: str | os.PathLike[str] | None = None,
                      expected_duration_s: float | None = None, outside: str = "hold",
                      seed: int = 0) -> TruthField:
    """The scenario's true field: main field at ``scenario.year``, the real crust, the seeded
    anomaly field (drawn for ``seed``) and its storm disturbance, each if the scenario has it.

    ``data_dir`` holds ``crust/EMM2017.COF`` and ``storms/intermagnet`` (default :func:`default_data_dir`);
    ``expected_duration_s`` is the mission length the ``compress`` rule spreads the storm
    window over (default :func:`expected_mission_duration_s`); ``outside`` is the policy of
    :class:`sitl.storms.StormDisturbance` for storm times past the data (``hold``, ``zero`` or
    ``raise``). Raises :class:`StormUnavailableError` naming the cause when the storm cannot
    be built.
    """
    model = main_field_model(scenario)
    quiet = TruthField(model=model, year=scenario.year, crustal_config=scenario.field_model.crustal,
                       crustal_origin=(scenario.start_lat_deg, scenario.start_lon_deg),
                       crust=crust_grid(scenario, data_dir)).for_seed(seed)
    storm = scenario.storm
    if not storm.enabled:   # a quiet day: what a space-weather feed says of it, if it is fed
        return replace(quiet, space_weather=quiet_index if storm.kp_feed else None,
                       ring_current=quiet_index if storm.symh_feed else None)
    from sitl import storms
    from sitl.storms.events import storm_event
    folder = Path(data_dir) if data_dir is not None else default_data_dir()
    try:
        event = storm_event(storm.event)
        disturbance = storms.StormDisturbance(event.deviations(folder, storm.stations), outside=outside)
    except (OSError, ValueError) as err:
        raise StormUnavailableError(f"scenario {scenario.name!r}: cannot load the storm data of {storm.event!r} from {folder}: "
                                    f"{err} (set FCMPC_DATA_DIR or --data-dir)") from err
    time_map = _storm_time_map(scenario, expected_duration_s)
    kp = _published(event.kp_series, folder, storm.kp_publication, seed, 0) if storm.kp_feed else None
    ring = _published(event.ring_series, folder, storm.ring_publication, seed, 1) if storm.symh_feed else None
    return replace(quiet, disturbance=disturbance, storm_time_s=time_map.storm_time_s, storm_scale=storm.scale,
                   space_weather=kp, ring_current=ring)


def _storm_time_map(scenario: Scenario, expected_duration_s: float | None = None):
    """Mission time -> storm time of the scenario's ``[storm] time_map`` (utc, or its window
    compressed onto the expected mission)."""
    from sitl import storms
    storm = scenario.storm
    if storm.time_map == "utc":
        return storms.StormTimeMap.utc(scenario.start_posix)
    start_s, end_s = storm.window_posix
    window = storms.StormWindow(f"{scenario.name} storm", start_s, end_s)
    duration = expected_duration_s if expected_duration_s is not None else expected_mission_duration_s(scenario)
    return storms.StormTimeMap.compress(window, duration)


def _published(read_series, folder: Path, publication, seed: int, stream: int):
    """The index of ``read_series(folder)`` as published (storm time POSIX s -> quick-look value),
    or None (no feed) when its file is absent."""
    from sitl.storms.published import PublishedIndex
    try:
        series = read_series(folder)
    except FileNotFoundError:
        return None
    return PublishedIndex(series, publication, seed, stream)


def storm_component_walks(scenario: Scenario, data_dir: str | os.PathLike[str] | None = None,
                          symh_ratio: float = 0.0) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """How the scenario's storm disturbance (dN, dE, dZ) moves along its route at the cruise speed,
    in mission time (:func:`sitl.storms.component_walks`): the short-lag rates (nT per sqrt(hour))
    and correlation times (hours, 0: random walk) a navigator set up for this world declares as
    ``FUS_BQA_N/E/Z`` and ``FUS_BQA_TN/TE/TZ``.

    ``symh_ratio`` > 0: what is left once a navigator removes the ring current predicted from
    SYM-H with that ratio (:mod:`companion.nav.ring_current`; along the main field's horizontal
    direction, from the mission's start), whose north may revert (the prediction's error comes
    and goes): the rates to declare as ``FUS_SYMH_N``, ``FUS_SYMH_TN`` and ``FUS_BQA_E/Z``."""
    from sitl import storms
    from sitl.storms.rates import MAY_REVERT
    disturbance = _storm_disturbance(scenario, data_dir, symh_ratio)
    may_revert = (True,) + tuple(MAY_REVERT[1:]) if symh_ratio > 0.0 else MAY_REVERT
    q, tau = storms.component_walks(disturbance, (scenario.start_lat_deg, scenario.start_lon_deg),
                                    (scenario.dest_lat_deg, scenario.dest_lon_deg),
                                    expected_mission_duration_s(scenario), may_revert)
    return tuple(float(v) for v in q), tuple(float(v) for v in tau)


def storm_component_correlations(scenario: Scenario, data_dir: str | os.PathLike[str] | None = None,
                                 symh_ratio: float = 0.0) -> tuple[float, float, float]:
    """The correlation (N-E, N-Z, E-Z) of the scenario's storm components' changes over one control
    step along its route in mission time (:func:`sitl.storms.component_correlations`): what a
    navigator set up for this world declares as ``FUS_BQA_RNE/RNZ/REZ``, or with ``symh_ratio`` > 0
    (see :func:`storm_component_walks`) as ``FUS_SYMH_RNE/RNZ``."""
    from sitl import storms
    return storms.component_correlations(_storm_disturbance(scenario, data_dir, symh_ratio),
                                         (scenario.start_lat_deg, scenario.start_lon_deg),
                                         (scenario.dest_lat_deg, scenario.dest_lon_deg),
                                         expected_mission_duration_s(scenario))


def _storm_disturbance(scenario: Scenario, data_dir: str | os.PathLike[str] | None, symh_ratio: float):
    """The scenario's storm disturbance ``(lat, lon, elapsed_s) -> (dN, dE, dZ)`` in nT, less the
    ring current predicted from SYM-H with ``symh_ratio`` (0: none removed), whether or not the
    navigator is fed the index."""
    truth = build_truth_field(scenario, data_dir)
    if truth.disturbance is None:
        raise ValueError(f"scenario {scenario.name!r} has no storm")
    if symh_ratio <= 0.0:
        return truth.storm_ned_nt
    # the ring current as it was (definitive, between the bins' centres), not as published
    from sitl.storms.events import storm_event
    series = storm_event(scenario.storm.event).ring_series(data_dir)
    storm_time = _storm_time_map(scenario).storm_time_s

    def ring(elapsed_s):
        return np.interp(storm_time(np.atleast_1d(elapsed_s)), series.start_s + 0.5 * series.length_s, series.value)
    reference = float(ring(0.0)[0])

    def disturbance(lat, lon, elapsed_s):
        ned = np.array(truth.storm_ned_nt(lat, lon, elapsed_s), dtype=float)
        main = truth.main_ned_nt(lat, lon, scenario.alt_m)
        change = symh_ratio * (ring(elapsed_s) - reference)
        along_h = main[..., :2] / np.hypot(main[..., 0], main[..., 1])[..., None]
        ned[..., :2] -= change[..., None] * along_h
        return ned
    return disturbance

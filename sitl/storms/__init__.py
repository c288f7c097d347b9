"""Real magnetic-storm data and the storm disturbance field of the SITL: the storm library.

The simulated vehicle sees ``main field + crust + storm disturbance`` (paper Section 4.2). This
package provides the disturbance, built from observatory data of real storms (one table of events,
:mod:`sitl.storms.events`: May 2024 from INTERMAGNET, Halloween 2003 from the GEM challenge files,
St Patrick's Day 2015 from SuperMAG, March 2011 from JMA), readers for the indices that document
them (OMNI SYM-H/AE, GFZ and CelesTrak Kp, DTU's RC), and those indices as a vehicle receives them:
published after a delay, with quick-look errors (:mod:`sitl.storms.published`). What follows
describes the May 2024 data; the other storms' readers say what differs.

Conventions (see :mod:`companion`)
    * Field vectors are geographic North-East-Down in nT: ``(dn, de, dd)`` = (dX, dY, dZ).
    * Times are **POSIX seconds, UTC, float64** (``time_s``), everywhere in this module:
      file time stamps, baselines, windows and queries. :func:`utc_s` converts an ISO
      string. Storm time is mapped onto mission time by :class:`StormTimeMap` and by the
      ``time_offset_s`` of :class:`StormDisturbance`.
    * Latitude/longitude in degrees; longitudes are accepted in either -180..180 or
      0..360 (IAGA-2002 files store 0..360 east).

Quiet baseline (:data:`QUIET_BASELINE`)
    A station's disturbance is its recorded field minus the **median of each component over
    2024-05-10 12:00-17:00 UTC**, the five hours before the storm sudden commencement
    (17:07 UTC). This interval is local night at the four western-Pacific stations (KAK,
    GUA, CTA, CNB: about 21-03 local time), where the solar-quiet (Sq) current system is
    weakest: there each component stays within 35 nT peak-to-peak and changes by less than
    10 nT in any 2 minutes (tested), against storm deviations of several hundred nT. Kp was
    3+ in 12-15 UTC (not a textbook quiet interval; no quiet day is in the files). The
    median is robust to short pulsations. FRD is in local morning then and its Y drifts by
    70 nT in the interval (Sq); ``StormDisturbance.from_records`` accepts a per-station
    window if that matters (FRD weighs about 1 % in the western Pacific).
    The diurnal Sq variation is **not** removed: the deviations contain the storm *and*
    the regular day-time Sq variation (tens of nT at mid latitudes). The secular variation
    over two days (< 0.1 nT) is negligible.

Spatial interpolation (:class:`StormDisturbance`)
    Inverse-distance weighting (Shepard, power 2) on the great-circle angle between the
    query point and the stations. With five stations (four in the western Pacific
    35S-36N, one in the eastern USA) no covariance model can be fitted, so a
    kriging/Gaussian-process fit would rest on an invented range parameter; IDW has none
    beyond the power. IDW reproduces each station exactly at its own location, is a convex
    combination (it never invents a disturbance larger than one observed), is smooth
    (power 2: differentiable everywhere, so the disturbance adds no kinks to the D/I
    gradients the MPC estimates; an exponential-covariance kriging would put a cusp at
    every station) and is fast. Its limits: flat spots (zero gradient) at the stations;
    far from every station it tends to a weighted mean of the stations; it ignores the
    latitude/local-time structure of the storm field, so it is meaningful only near the
    network (the paper's mission area 27-34N, 145-165E lies between KAK and GUA, which
    carry 83-95 % of the weight there). NED components of different stations are
    combined as they are, each in its own local frame, as gridded observatory products
    do (the meridians of KAK and GUA converge by about 2 degrees, so a few percent of dX
    leaks into dY).

Data acknowledgement: INTERMAGNET; observatories KAK (JMA), GUA, FRD (USGS), CTA, CNB
(Geoscience Australia). Any figure showing these data must carry
:data:`ACKNOWLEDGEMENT` (the plot function does).
"""
from __future__ import annotations

# One module per idea; ``from sitl.storms import X`` keeps working for every public name:
#   common       time helpers, data folder, error type, the storm windows of 10 May 2024
#   iaga         IAGA-2002 reader and load_stations
#   omni         OMNI AE / SYM-H reader
#   kp           GFZ Kp reader
#   deviation    quiet baseline, station deviations, eq. 64, (D, I) shift
#   disturbance  StormDisturbance: the interpolated disturbance field
#   timemap      StormTimeMap and sharpest_window
#   plot         plot_disturbance (matplotlib, lazily)
#   published    indices as published: IndexSeries, Publication (delays, quick-look errors), PublishedIndex
#   rc celestrak RC (HDF5) and CelesTrak Kp readers; gem2008, supermag: the other storms' station readers
#   dipole       IGRF's dipole: geomagnetic coordinates, rotation of dipole axes to geographic
#   events       the storm library's table (events.toml) and its readers
#   rates        component_rates, component_walks, component_correlations: how the disturbance moves along a route (a navigator's declared walk)
from sitl.storms.common import (ACKNOWLEDGEMENT, DEFAULT_STATIONS, KP_FILE, LONG_STORM, OMNI_FILE, QUIET_BASELINE, SHORT_STORM,
                                SUDDEN_COMMENCEMENT_S, StormDataError, StormWindow, default_data_dir, utc_s)
from sitl.storms.deviation import (StationDeviation, di_shift_deg, eq64_dbh_nt, quiet_baseline,
                                   station_deviation)
from sitl.storms.disturbance import StormDisturbance
from sitl.storms.iaga import IagaRecord, load_stations, read_iaga2002
from sitl.storms.kp import KpRecord, read_gfz_kp
from sitl.storms.omni import OmniIndices, read_omni_symh
from sitl.storms.plot import plot_disturbance
from sitl.storms.published import IndexSeries, Publication, PublishedIndex
from sitl.storms.rates import component_correlations, component_rates, component_walks
from sitl.storms.timemap import StormTimeMap, sharpest_window

__all__ = [
    "ACKNOWLEDGEMENT",
    "DEFAULT_STATIONS",
    "KP_FILE",
    "LONG_STORM",
    "OMNI_FILE",
    "QUIET_BASELINE",
    "SHORT_STORM",
    "SUDDEN_COMMENCEMENT_S",
    "IagaRecord",
    "IndexSeries",
    "Publication",
    "PublishedIndex",
    "KpRecord",
    "OmniIndices",
    "StationDeviation",
    "StormDataError",
    "StormDisturbance",
    "StormTimeMap",
    "StormWindow",
    "default_data_dir",
    "di_shift_deg",
    "eq64_dbh_nt",
    "load_stations",
    "plot_disturbance",
    "quiet_baseline",
    "component_rates",
    "component_correlations",
    "component_walks",
    "read_gfz_kp",
    "read_iaga2002",
    "read_omni_symh",
    "sharpest_window",
    "station_deviation",
    "utc_s",
]

"""Error sources of the realistic world: switch each on or off, and predict what each costs.

Sources (names for ``fcmpc-montecarlo --errors`` and ``--budget``):

``heading``
    the attitude errors of the declared heading source (bias, drift, INS azimuth psi_z, compass
    yaw against the IGRF table) and the tilt errors; off: a true heading, white noise only.
``main_field``
    IGRF-14 as the truth's main field while the navigator keeps WMM; off: the truth is WMM.
``crustal``
    the crust: the real one (EMM2017, ``[field] crust``) and the seeded anomaly field, as the
    realistic preset has them; off: none.
``calibration``
    the hard/soft-iron residuals and temperature drift; off: a perfect calibration.
``noise``
    white magnetometer and attitude noise and the magnetometer's resolution; off: none.
``storm``
    the scenario's storm disturbance (storm scenarios only); off: quiet.
``motion``
    the vehicle's motion errors (water current, speed scale, course bias; ``[vehicle]``): what
    makes dead reckoning on the commands drift; off: the vehicle goes exactly where commanded.
``ins``
    the INS's initial errors and gyro drift (Table 1); off: a perfect INS. With the ``ins``
    heading source the INS azimuth error is the heading error, so the budget's ``heading`` row
    keeps the INS on and its ``ins`` row has a true heading: each row is one physical effect.

:func:`predicted_fix_error` gives, per source and seed, the (D, I) error ``e`` the source puts
on the measurement at the destination and the geomagnetic fix error ``|G^-1 e|`` it implies,
with ``G`` the navigator's model gradient there: what the fix alone would miss by at the end.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from companion.frames import mats_nb_from_euler
from companion.nav.field import decl_incl_gradient, model_for_date
from companion.nav.geo import WGS84
from sitl.scenario import Scenario, ins_declaration
from sitl.world.attitude import AttitudeErrorConfig, AttitudeErrors
from sitl.world.ins import InsErrorConfig, InsErrorModel
from sitl.world.magerrors import MagErrors
from sitl.world.magnetic import TruthField, decl_incl_from_ned
from sitl.world.vehicle import MotionErrorConfig

__all__ = ["SOURCES", "parse_errors", "with_errors", "only", "SourceError", "predicted_fix_error"]

SOURCES = ("heading", "main_field", "crustal", "calibration", "noise", "storm", "motion", "ins")
PERFECT_INS = InsErrorConfig(misalign_arcmin=(0.0, 0.0, 0.0), vel_err_mps=0.0, pos_err_east_m=0.0,
                             pos_err_north_m=0.0, gyro_bias_degph=0.0, gyro_markov_degph=0.0, deterministic=True)


def parse_errors(spec: str) -> dict[str, bool]:
    """``"-heading,+crustal"`` -> {"heading": False, "crustal": True}; ``"none"``/``"all"`` for all."""
    result: dict[str, bool] = {}
    for item in (part.strip() for part in spec.split(",") if part.strip()):
        if item in ("none", "all"):
            result.update({name: item == "all" for name in SOURCES})
            continue
        sign, name = (item[0], item[1:]) if item[0] in "+-" else ("+", item)
        name = name.replace("-", "_")
        if name not in SOURCES:
            raise ValueError(f"unknown error source {name!r}; choose from {', '.join(SOURCES)} (or none, all)")
        result[name] = sign == "+"
    return result


def with_errors(scenario: Scenario, switches: dict[str, bool], real: Scenario) -> Scenario:
    """``scenario`` with each named source switched on (as in ``real``, the realistic preset)
    or off; sources not named keep ``scenario``'s setting."""
    s = scenario
    for name, on in switches.items():
        if name == "heading":
            s = replace(s, attitude=real.attitude if on else AttitudeErrorConfig())
        elif name == "main_field":
            s = replace(s, field_model=replace(s.field_model, main=real.field_model.main if on else "wmm"))
        elif name == "crustal":
            crustal = real.field_model.crustal if on else replace(real.field_model.crustal, enabled=False)
            s = replace(s, field_model=replace(s.field_model, crustal=crustal,
                                               crust=real.field_model.crust if on else "none"))
        elif name == "calibration":
            keys = ("mag_hard_iron_resid_nt", "mag_soft_iron_resid", "mag_temp_coeff_nt_per_k", "mag_temp_swing_k")
            s = replace(s, sensors=replace(s.sensors, **{k: getattr(real.sensors, k) if on else 0.0 for k in keys}))
        elif name == "noise":
            keys = ("mag_noise_nt", "mag_lsb_nt", "attitude_noise_deg")
            s = replace(s, sensors=replace(s.sensors, **{k: getattr(real.sensors, k) if on else 0.0 for k in keys}))
        elif name == "storm":
            s = replace(s, storm=replace(s.storm, enabled=on and real.storm.enabled))
        elif name == "motion":
            s = replace(s, motion=real.motion if on else MotionErrorConfig())
        elif name == "ins":
            # the navigator keeps the real INS's datasheet: a world whose INS happens to be
            # perfect does not tell the navigator so (what the [navigator] table sets wins)
            declared = {**(ins_declaration(real.ins) if real.ins.onboard else {}), **dict(s.navigator)}
            # the INS's errors, not whether the vehicle carries one (``--no-ins``: ``ins.onboard``)
            s = replace(s, ins=replace(real.ins if on else PERFECT_INS, onboard=s.ins.onboard),
                        navigator=tuple(declared.items()))
    # the sample-by-sample path whenever anything of the realistic world is on
    return replace(s, sensors=replace(s.sensors, inprocess_samples=real.sensors.inprocess_samples))


def only(real: Scenario, source: str | None) -> Scenario:
    """The realistic scenario with just ``source`` on (None: everything off; "all": as is)."""
    if source == "all":
        return real
    switches = {name: name == source for name in SOURCES}
    if source == "heading" and real.heading_source == "ins":
        switches["ins"] = True               # the INS azimuth error is this heading's error
    if source == "ins":
        switches["heading"] = False
    return with_errors(real, switches, real)


@dataclass(frozen=True)
class SourceError:
    """One seed's (D, I) error at the destination, degrees, and the fix error ``|G^-1 e|`` in m."""

    decl_deg: float
    incl_deg: float
    fix_error_m: float


def _end_of_route_ins(scenario: Scenario, seed: int, duration_s: float) -> InsErrorModel:
    """The run's INS (same stream as ``fly_in_process``) propagated along the geodesic at cruise."""
    ins_seed = np.random.SeedSequence(seed).spawn(5)[0]
    ins = InsErrorModel(scenario.ins, np.random.default_rng(ins_seed), scenario.start_lat_deg)
    line = WGS84.InverseLine(scenario.start_lat_deg, scenario.start_lon_deg, scenario.dest_lat_deg,
                             scenario.dest_lon_deg)
    steps = max(1, int(duration_s // 360.0))
    speed = line.s13 / duration_s
    for k in range(steps):
        p = line.Position(line.s13 * (k + 0.5) / steps)
        course = math.radians(p["azi2"])
        ins.propagate(duration_s / steps, p["lat2"], speed * math.sin(course), speed * math.cos(course))
    return ins


def predicted_fix_error(real: Scenario, source: str, seed: int, duration_s: float,
                        truth_factory) -> SourceError:
    """The (D, I) error ``source`` alone puts on the destination's measurement for ``seed``.

    ``truth_factory(scenario)`` builds a :class:`TruthField` (``sitl.world.build``). Heading:
    the yaw error at the end of the mission is the D error; calibration: the residual applied to
    the destination's body field on the route's final course; noise: one averaged-noise draw;
    fields: truth minus the navigator's model. ``ins`` and ``motion``: the fix does not use the
    INS or the dead reckoning: e = 0.
    """
    lat, lon, alt, year = real.dest_lat_deg, real.dest_lon_deg, real.alt_m, real.year
    nav_model = model_for_date(year)
    nav = nav_model.elements(lat, lon, alt, year)
    s_nav = np.array([float(nav.decl_deg), float(nav.incl_deg)])
    nav_ned = np.array([float(nav.x_nt), float(nav.y_nt), float(nav.z_nt)])
    rng = np.random.default_rng([seed, 0xB0D6E7])
    line = WGS84.Inverse(real.start_lat_deg, real.start_lon_deg, lat, lon)
    course = math.radians(line["azi2"])
    e = np.zeros(2)
    if source in ("main_field", "crustal", "storm"):
        truth: TruthField = truth_factory(only(real, source)).for_seed(seed)
        ned = truth.field_ned_nt(lat, lon, alt, duration_s)
        e = np.array([float(v) for v in decl_incl_from_ned(*ned)]) - s_nav
    elif source == "heading":
        config = real.attitude
        if config.heading_source == "ins":
            e[0] = math.degrees(_end_of_route_ins(real, seed, duration_s).attitude_error_rad(course)[2])
        elif config.heading_source == "true":
            errors = AttitudeErrors(config, np.random.default_rng(np.random.SeedSequence(seed).spawn(5)[2]))
            e[0] = math.degrees(errors.heading_bias_rad + errors.advance(duration_s))
        else:   # magnetic: D measured = the IGRF table at the FC's (INS) position
            from sitl.world.igrf import igrf14_model
            ins = _end_of_route_ins(real, seed, duration_s)
            fc_lat, fc_lon = ins.indicated_position(lat, lon)
            e[0] = float(igrf14_model(year).elements(fc_lat, fc_lon, alt, year).decl_deg) - s_nav[0]
    elif source == "calibration":
        mag = MagErrors.draw(real.sensors.mag_errors, np.random.default_rng(np.random.SeedSequence(seed).spawn(5)[3]))
        c_nb = mats_nb_from_euler(0.0, 0.0, course)
        body = c_nb.T @ nav_ned
        ned = c_nb @ mag.apply(body, duration_s)
        e = np.array([float(v) for v in decl_incl_from_ned(*ned)]) - s_nav
    elif source == "noise":
        sigma = real.sensors.averaged_di_noise_deg(360.0, float(nav.h_nt), float(nav.f_nt))
        e = rng.normal(0.0, 1.0, 2) * np.array(sigma)
    g = decl_incl_gradient(nav_model, lat, lon, alt, year)
    fix = np.linalg.solve(g, e) if np.any(e) else np.zeros(2)
    return SourceError(float(e[0]), float(e[1]), float(np.hypot(*fix)))

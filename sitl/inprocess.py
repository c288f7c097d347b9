"""One mission flown in-process: the navigation core against the simulated world, no sockets.

The Monte Carlo and the tests use this; the MAVLink simulator wraps the same world models.
Per control period the vehicle tracks the last command (kinematics at ``substep_s``), the
INS error propagates along the true track, and the companion's measurement is formed as it
would be on the vehicle: D and I of the true field averaged along the period's path, plus the
averaged sensor noise of the scenario (:meth:`SensorModel.averaged_di_noise_deg`).

Seeding: one ``numpy.random.SeedSequence(seed)`` spawns independent streams for the INS
errors and the measurement noise, so LTI-, LTV- and Fc-MPC meet the same INS and the same
noise for the same seed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.nav.mission import Command, Measurement, Mission, Phase
from companion.nav.geo import geodesic_distance_m
from companion.params import Controller, NavConfig
from sitl.scenario import Scenario
from sitl.world.ins import InsErrorModel
from sitl.world.magnetic import TruthField
from sitl.world.vehicle import VehicleState, step_vehicle

__all__ = ["RunResult", "fly_in_process"]


@dataclass(frozen=True)
class RunResult:
    """What one run produced; positions in degrees at each control step (start included)."""

    controller: str
    seed: int
    phase: str
    reason: str
    iterations: int
    true_lat_deg: np.ndarray
    true_lon_deg: np.ndarray
    est_lat_deg: np.ndarray
    est_lon_deg: np.ndarray
    remaining_m: float          # true distance from the final position to the destination
    length_m: float             # path length actually flown
    duration_s: float
    ins_error_m: np.ndarray     # INS position error magnitude at each step
    commands: tuple[Command, ...] = field(default=(), repr=False)

    @property
    def arrived(self) -> bool:
        return self.phase == Phase.ARRIVED


def fly_in_process(nav: NavConfig, scenario: Scenario, seed: int, truth: TruthField,
                   substep_s: float = 30.0, keep_commands: bool = False) -> RunResult:
    """Fly one seeded mission to its end (arrival, failure or the step limit)."""
    ins_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
    noise_rng = np.random.default_rng(noise_seed)
    ins = InsErrorModel(scenario.ins, np.random.default_rng(ins_seed), nav.start_lat_deg)
    mission = Mission(nav, truth.model)
    state = VehicleState(nav.start_lat_deg, nav.start_lon_deg)
    start_field = truth.model.elements(nav.start_lat_deg, nav.start_lon_deg, nav.alt_m, nav.year)
    sigma_d, sigma_i = scenario.sensors.averaged_di_noise_deg(nav.period_s, float(start_field.h_nt),
                                                              float(start_field.f_nt))
    substeps = max(1, int(round(nav.period_s / substep_s)))
    dt = nav.period_s / substeps

    def measure(time_s: float, lats: np.ndarray, lons: np.ndarray, window_s: float) -> Measurement:
        d, i = truth.decl_incl_deg(lats, lons, nav.alt_m, time_s)
        ins_lat, ins_lon = ins.indicated_position(state.lat_deg, state.lon_deg)
        return Measurement(time_s, float(np.mean(d)) + noise_rng.normal(0.0, sigma_d),
                           float(np.mean(i)) + noise_rng.normal(0.0, sigma_i), ins_lat, ins_lon, window_s)

    time_s = 0.0
    lats, lons = [state.lat_deg], [state.lon_deg]
    est_lats, est_lons, ins_err = [state.lat_deg], [state.lon_deg], [math.hypot(*ins.position_error_m(state.lat_deg))]
    command = mission.step(measure(time_s, np.array([state.lat_deg]), np.array([state.lon_deg]), 0.0))
    commands = [command]
    while not command.done:
        path_lat, path_lon = [], []
        for _ in range(substeps):
            state = step_vehicle(state, dt, command.course_rad, command.speed_mps, scenario.vehicle)
            ins.propagate(dt, state.lat_deg, state.vel_east_mps, state.vel_north_mps)
            path_lat.append(state.lat_deg)
            path_lon.append(state.lon_deg)
        time_s += nav.period_s
        command = mission.step(measure(time_s, np.array(path_lat), np.array(path_lon), nav.period_s))
        if keep_commands:
            commands.append(command)
        lats.append(state.lat_deg)
        lons.append(state.lon_deg)
        est_lats.append(command.est_lat_deg)
        est_lons.append(command.est_lon_deg)
        ins_err.append(math.hypot(*ins.position_error_m(state.lat_deg)))
    return RunResult(
        controller=Controller.NAMES[nav.controller], seed=seed, phase=command.phase, reason=command.reason,
        iterations=command.step, true_lat_deg=np.array(lats), true_lon_deg=np.array(lons),
        est_lat_deg=np.array(est_lats), est_lon_deg=np.array(est_lons),
        remaining_m=geodesic_distance_m(state.lat_deg, state.lon_deg, nav.dest_lat_deg, nav.dest_lon_deg),
        length_m=state.distance_m, duration_s=time_s, ins_error_m=np.array(ins_err),
        commands=tuple(commands) if keep_commands else (),
    )

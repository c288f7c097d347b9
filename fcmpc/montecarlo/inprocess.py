"""One mission flown in-process: the navigation core against the simulated world, no sockets.

The Monte Carlo and the tests use this; the MAVLink simulator wraps the same world models.
Per control period the vehicle tracks the last command (kinematics at ``substep_s``), the
INS error propagates along the true track, and the period's average goes to the companion's own
navigation step (:meth:`companion.nav.navigator.Navigator.step`: the measurement, the plausibility
judge, the core), as on the vehicle. Two paths to the period's average
(:class:`companion.nav.period.PeriodAverage`), chosen by the scenario's ``[sensors] inprocess_samples``:

* analytic (the paper's ideal worlds, ``paper_pacific`` and the paper's storm presets): D and I of the true
  field averaged along the period's path, plus the averaged sensor noise of the scenario
  (:meth:`SensorModel.averaged_di_noise_deg`), one normal each;
* samples (the realistic presets): every magnetometer and attitude sample of the period is
  simulated with the run's heading source, calibration residuals and noise, and averaged by
  the companion's own averager (:func:`sitl.world.sampling.sample_period`), the gravity samples
  waiting after a new command as the navigator asks (``StepResult.settle``).

Each step's average is kept in ``RunResult.elements``; the navigator forms its measurement from it
(which I, H and Z from F and I) for the elements of its set (NAV_ELEMENTS: 1 (D, I), 2 (I, F),
0 auto (D, I, F) with F weighed while quiet, ...). A period the plausibility judge excludes is
counted (``RunResult.excluded``) and the last command flies on, as on the vehicle.

The navigator's field model is its own (``Mission`` picks WMM from ``NavConfig``); the truth
field (``truth``) may be a different model plus crust and storm. The flight controller's
position, which the ``magnetic`` heading source evaluates its declination table at, is the
INS-indicated position (GPS is denied from the start).

Each step's measurement carries the standard error of every average, as the companion measures
it from the period's scatter: on the samples path computed from the samples
(:class:`companion.nav.period.PeriodAverager`); on the analytic path, which draws the average's
error directly, the scatter estimate is drawn from its own sampling distribution, ``sigma (1 +
1.166 z / sqrt(n))`` with ``n`` the period's samples (the MAD-based estimate's asymptotic
relative standard deviation, ``sqrt(1.36 / n)``: 2 % at 3600 samples).

Each step's measurement also carries the world's space-weather index (:meth:`TruthField.kp`: the
storm's own Kp at its storm time, NaN without a storm), as a ground station would set ``NAV_KP``,
and the ring-current index SYM-H at the step (:meth:`TruthField.symh`): the latest value, as the
companion has it from a ground station that keeps ``NAV_SYMH`` up to date (not the period's
average, which a vehicle is not told).

Seeding: one ``numpy.random.SeedSequence(seed)`` spawns independent streams: [0] INS errors,
[1] measurement noise (analytic D, I or the samples), [2] attitude errors, [3] calibration
residuals, [4] the analytic F/H/Z noise, [5] the analytic standard errors' scatter, [6] motion errors,
[7] accelerometer noise, [8] the true start's GPS error; the crustal field is drawn from ``seed`` by
:meth:`TruthField.for_seed`. LTI-, LTV- and Fc-MPC meet the same draws for the same seed, and
the ideal world's streams [0] and [1] are drawn exactly as before the others existed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.nav.elements import resolve_elements
from companion.nav.field import model_for_setting
from companion.nav.geo import enu_offset, geodesic_distance_m
from companion.nav.mission import Command, Mission, Phase
from companion.nav.navigator import SETTLE_AFTER_COMMAND_S, Navigator, Period
from companion.nav.period import PeriodAverage
from companion.params import Controller, NavConfig
from sitl.scenario import Scenario
from sitl.sensors import WaveMotion, make_error_models
from sitl.world.emm import OutsideGridError
from sitl.world.ins import InsErrorModel, propagate_together
from sitl.world.magnetic import TruthField
from sitl.world.sampling import PeriodKnots, SampleSettings, sample_period
from sitl.world.vehicle import VehicleState, seed_motion_errors, step_vehicle

__all__ = ["CHI2_95_2DOF", "InProcessFlight", "RunResult", "fly_batch", "fly_in_process", "nees_per_step"]


CHI2_95_2DOF = 5.991464547107979   # chi-square 95 % quantile, 2 degrees of freedom: the 95 % ellipse
MAD_SE_RELATIVE_SD = 1.1664        # sqrt(1.3605): asymptotic relative sd of 1.4826 MAD for normal samples


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
    remaining_m: float          # true distance to the destination where the vehicle comes to rest
    length_m: float             # path length actually flown
    duration_s: float
    ins_error_m: np.ndarray     # INS position error magnitude at each step
    commands: tuple[Command, ...] = field(default=(), repr=False)
    elements: tuple[PeriodAverage, ...] = field(default=(), repr=False)  # measured, per step
    # the estimate's covariance (east-east, east-north, north-north, m^2) at each step, NaN
    # where the navigator has none (LTI/LTV-MPC, Table 3's path between fusions)
    est_cov_en_m2: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    process_model: str = ""
    # where the vehicle comes to rest on the final command (:meth:`InProcessFlight.at_rest`)
    rest_lat_deg: float = math.nan
    rest_lon_deg: float = math.nan
    excluded: int = 0           # periods the plausibility judge excluded (the last command flew on)

    def track_to_rest(self) -> tuple[np.ndarray, np.ndarray]:
        """The true track with its last point where the vehicle came to rest (the miss's end)."""
        lat, lon = self.true_lat_deg.copy(), self.true_lon_deg.copy()
        if math.isfinite(self.rest_lat_deg) and len(lat):
            lat[-1], lon[-1] = self.rest_lat_deg, self.rest_lon_deg
        return lat, lon

    @property
    def arrived(self) -> bool:
        return self.phase == Phase.ARRIVED


def fly_in_process(nav: NavConfig, scenario: Scenario, seed: int, truth: TruthField,
                   substep_s: float = 30.0, keep_commands: bool = False,
                   nav_model=None) -> RunResult:
    """Fly one seeded mission to its end (arrival, failure or the step limit).

    ``nav_model`` is the navigator's field model; by default ``truth.model`` when the truth's
    main field is the navigator's WMM (the ideal world), else the model ``NavConfig`` names.
    """
    return fly_batch([InProcessFlight(nav, scenario, seed, truth, substep_s, keep_commands, nav_model)])[0]


def fly_batch(flights: list[InProcessFlight]) -> list[RunResult]:
    """Fly several missions side by side to their ends, each exactly as :func:`fly_in_process`
    flies it alone (bit for bit: every flight keeps its own random streams, and the INS of the
    flights that move together propagate as one stacked computation,
    :func:`sitl.world.ins.propagate_together`, which gives each model's own numbers). Per
    sub-step, the Python overhead of the INS's small matrix products is paid once for all of them:
    the Monte Carlo flies its batches so."""
    active = [f for f in flights if not f.done]
    while active:
        longest = max(f.substeps for f in active)
        for f in active:
            f.begin_period()
        for index in range(longest):
            moving = [f for f in active if index < f.substeps]
            for f in moving:
                f.move()
            propagate_together([f.ins for f in moving], [f.dt_s for f in moving], [f.state for f in moving])
            for f in moving:
                f.record_knot(index)
        for f in active:
            try:
                f.end_period()
            except OutsideGridError as err:   # the vehicle left the simulated world: a failed run, not a crash
                f.left_world = str(err)
        active = [f for f in active if not f.done]
    return [f.result() for f in flights]


class InProcessFlight:
    """One seeded mission between its control steps: the simulated world (vehicle, INS, sensors,
    truth field) and the navigator. Built at the start (the start-up measurement and first
    step taken); :func:`fly_batch` moves it sub-step by sub-step and ends each period."""

    def __init__(self, nav: NavConfig, scenario: Scenario, seed: int, truth: TruthField,
                 substep_s: float = 30.0, keep_commands: bool = False, nav_model=None) -> None:
        # (spawn by index: a new stream leaves the older ones, and so every older draw, as they were)
        ins_seed, noise_seed, att_seed, cal_seed, fhz_seed, se_seed, _motion, accel_seed, start_seed = \
            np.random.SeedSequence(seed).spawn(9)
        self.accel_rng = np.random.default_rng(accel_seed)
        if scenario.heading_source == "magnetic":   # as the companion does: never D with a compass yaw
            nav = nav.replace(elements=resolve_elements(nav.elements, compass_derived=True))
        self.nav, self.scenario, self.seed, self.keep_commands = nav, scenario, seed, keep_commands
        self.noise_rng = np.random.default_rng(noise_seed)
        self.fhz_rng = np.random.default_rng(fhz_seed)
        self.se_rng = np.random.default_rng(se_seed)
        self.ins = InsErrorModel(scenario.ins, np.random.default_rng(ins_seed), nav.start_lat_deg)
        self.truth = truth = truth.for_seed(seed)
        if nav_model is None and scenario.field_model.main == "wmm":
            # the ideal world: the navigator's WMM is the truth's own, when it is the model the
            # navigator picks for its NAV_YEAR (a navigator set to another date picks its own)
            wanted = model_for_setting(nav.year, nav.wmm, nav.nav_map)
            nav_model = truth.model if wanted.name == truth.model.name else wanted
        self.mission = Mission(nav, nav_model)
        # the navigator starts from a GPS fix (NAV_START), declared with the receiver's noise (denied
        # after); the vehicle is truly one receiver error away from it (none with exact_start)
        self.mission.set_start_fix(nav.gps_sigma_m)
        self.navigator = Navigator(self.mission)
        self.settle_until_s = -math.inf   # gravity samples wait after a new command (StepResult.settle)
        self.excluded = 0
        self.left_world = ""              # why the vehicle left the simulated world (a failed run)
        self.state = state = VehicleState(*scenario.true_start(np.random.default_rng(start_seed),
                                                               (nav.start_lat_deg, nav.start_lon_deg)))
        sensors = scenario.sensors
        self.sampled = sensors.inprocess_samples
        self.substeps = max(1, int(round(nav.period_s / substep_s)))
        self.dt_s = nav.period_s / self.substeps
        self.errors = make_error_models(scenario, np.random.default_rng(att_seed), np.random.default_rng(cal_seed))
        self.motion = seed_motion_errors(scenario.motion, seed)   # stream [6], as the firmware's world draws it
        if not self.sampled:
            start_field = truth.model.elements(nav.start_lat_deg, nav.start_lon_deg, nav.alt_m, truth.year)   # the world's date
            self.sigma_d, self.sigma_i = sensors.averaged_di_noise_deg(nav.period_s, float(start_field.h_nt),
                                                                       float(start_field.f_nt))
            samples = max(1.0, sensors.mag_rate_hz * nav.period_s)
            self.sigma_f = sensors.mag_noise_nt / math.sqrt(samples)
            self.se_spread = MAD_SE_RELATIVE_SD / math.sqrt(samples)
        self.settings = SampleSettings(sensors.mag_rate_hz, sensors.mag_noise_nt, sensors.mag_lsb_nt,
                                       sensors.mag_bias_nt, sensors.attitude_noise_deg, scenario.heading_source,
                                       sensors.accel_noise_mps2)
        self.wave = WaveMotion()
        self.mag_apply = self.errors.mag.apply if self.errors.mag is not None else None

        self.time_s = 0.0
        self.lats, self.lons = [state.lat_deg], [state.lon_deg]
        self.ins_err = [math.hypot(*self.ins.position_error_m(state.lat_deg))]
        self.commands, self.elements, self.est_lats, self.est_lons, self.covs = [], [], [], [], []
        self._step(self._measure(0.0, [(0.0, state, *self._slow_errors(0.0, state))], 0.0), first=True)
        self.knots: list = []

    @property
    def done(self) -> bool:
        return bool(self.left_world) or self.command.done

    # --- one period, sub-step by sub-step ---------------------------------------------------------
    def begin_period(self) -> None:
        self.knots = [(self.time_s, self.state, *self._slow_errors(self.time_s, self.state))]

    def move(self) -> None:
        """The vehicle's next sub-step on the last command (the INS follows: :func:`fly_batch`)."""
        self.state = step_vehicle(self.state, self.dt_s, self.command.course_rad, self.command.speed_mps,
                                  self.scenario.vehicle, self.motion)

    def record_knot(self, index: int) -> None:
        t = self.time_s + (index + 1) * self.dt_s
        self.knots.append((t, self.state, *self._slow_errors(t, self.state)))

    def end_period(self) -> None:
        """The period's average and the navigator's step on it."""
        state = self.state
        self.time_s += self.nav.period_s
        self._step(self._measure(self.time_s, self.knots, self.nav.period_s))
        self.lats.append(state.lat_deg)
        self.lons.append(state.lon_deg)
        self.ins_err.append(math.hypot(*self.ins.position_error_m(state.lat_deg)))

    def _step(self, period: Period, first: bool = False) -> None:
        """The navigator's step on ``period``: its command flown from now on, or the last one flown
        on when the period is excluded (counted)."""
        result = self.navigator.step(period)
        if result.command is None:
            self.excluded += 1
        else:
            self.command = result.command
            if result.settle:
                self.settle_until_s = period.time_s + SETTLE_AFTER_COMMAND_S
        command = self.command
        self.elements.append(period.average)
        if self.keep_commands or first:
            self.commands.append(command)
        self.est_lats.append(command.est_lat_deg)
        self.est_lons.append(command.est_lon_deg)
        self.covs.append(command.est_cov_en_m2)

    def result(self) -> RunResult:
        nav, command, mission = self.nav, self.command, self.mission
        state = self.at_rest()
        return RunResult(
            controller=Controller.NAMES[nav.controller], seed=self.seed,
            phase=Phase.FAILED if self.left_world else command.phase, reason=self.left_world or command.reason,
            iterations=command.step, true_lat_deg=np.array(self.lats), true_lon_deg=np.array(self.lons),
            est_lat_deg=np.array(self.est_lats), est_lon_deg=np.array(self.est_lons),
            remaining_m=geodesic_distance_m(state.lat_deg, state.lon_deg, nav.dest_lat_deg, nav.dest_lon_deg),
            length_m=state.distance_m, duration_s=self.time_s, ins_error_m=np.array(self.ins_err),
            commands=tuple(self.commands) if self.keep_commands else (), elements=tuple(self.elements),
            est_cov_en_m2=np.array(self.covs, dtype=float),
            process_model=mission.estimator.process_name if mission.estimator is not None else "table3",
            rest_lat_deg=state.lat_deg, rest_lon_deg=state.lon_deg, excluded=self.excluded,
        )

    def at_rest(self) -> VehicleState:
        """Where the vehicle comes to rest on the final command (zero speed, at its deceleration
        limit): the mission's miss. At the final step it may still be moving at the last leg's
        speed (6.4 m/s median on the quiet route without NAV_FINAL_LEG, 40 m more to go)."""
        limits = self.scenario.vehicle
        if not (self.command.done and self.state.speed_mps > 0.0 and limits.accel_mps2 > 0.0):
            return self.state
        return step_vehicle(self.state, self.state.speed_mps / limits.accel_mps2, self.command.course_rad, 0.0,
                            limits, self.motion)

    # --- the world's side -------------------------------------------------------------------------
    def _slow_errors(self, time_s: float, s: VehicleState) -> tuple[tuple[float, float, float], float]:
        """The attitude's slow errors and the FC's table declination at a sub-step."""
        errors = self.errors
        slow = (0.0, 0.0, 0.0)
        if errors.attitude is not None:
            slow = errors.attitude.slow_errors_rad(time_s, s.course_rad, self.ins)
        decl = math.nan
        if errors.decl_table_deg is not None:
            decl = float(errors.decl_table_deg(*self.ins.indicated_position(s.lat_deg, s.lon_deg)))
        return slow, decl

    def _measure(self, time_s: float, knots: list, window_s: float) -> Period:
        """The period ending at ``time_s`` as the navigator is given it. ``knots``: (time, state,
        slow errors, table declination) from the period's start."""
        nav, truth, ins, state = self.nav, self.truth, self.ins, self.state
        lats = np.array([k[1].lat_deg for k in knots])
        lons = np.array([k[1].lon_deg for k in knots])
        times = np.array([k[0] for k in knots])
        ins_lat, ins_lon = ins.indicated_position(state.lat_deg, state.lon_deg) if self.scenario.ins.onboard \
            else (math.nan, math.nan)
        ned = truth.field_ned_nt(lats, lons, nav.alt_m, times)
        if self.sampled:
            period = PeriodKnots(times, ned, np.array([k[1].course_rad for k in knots]),
                                 np.array([k[2] for k in knots]), np.array([k[3] for k in knots]))
            avg = sample_period(period, self.settings, self.wave.tilt_rad, self.mag_apply, self.noise_rng,
                                self.accel_rng, self.settle_until_s)
        else:
            avg = self._analytic_average(time_s, ned, window_s)
        return Period(time_s, avg, window_s, ins_lat, ins_lon, truth.kp(time_s), truth.symh(time_s))

    def _analytic_average(self, time_s: float, ned: np.ndarray, window_s: float) -> PeriodAverage:
        """The paper's worlds: the time average over the period's path, by the trapezoid rule over its
        knots (the start alone at step 0), plus the averaged sensor noise. Its centre is the period's
        midpoint, as for the companion's evenly spaced samples; the knots after the start alone would
        put it half a sub-step late (15 s, ~200 m along the track at 50 km/h). A storm is averaged
        over the period's times too, as the samples would see it. (Streams [4] and [5] keep their
        draws per step, of which H's and Z's are no longer used: the navigator forms H and Z from F
        and I, as the companion does.)"""
        sigma_d, sigma_i, sigma_f = self.sigma_d, self.sigma_i, self.sigma_f
        n, e, d = ned[..., 0], ned[..., 1], ned[..., 2]
        h = np.hypot(n, e)
        weights = trapezoid_weights(len(ned))
        decl = float(weights @ np.degrees(np.arctan2(e, n))) + self.noise_rng.normal(0.0, sigma_d)
        incl = float(weights @ np.degrees(np.arctan2(d, h))) + self.noise_rng.normal(0.0, sigma_i)
        f_nt = float(weights @ np.sqrt(h * h + d * d)) + sigma_f * self.fhz_rng.normal()
        self.fhz_rng.normal(), self.fhz_rng.normal()
        # the standard errors as the period's scatter would measure them (D, I, F; H's and Z's unused)
        se = np.array([sigma_d, sigma_i, sigma_f, sigma_f, sigma_f]) * np.maximum(
            0.0, 1.0 + self.se_spread * self.se_rng.standard_normal(5))
        count = int(round(self.scenario.sensors.mag_rate_hz * self.nav.period_s))
        return PeriodAverage(decl, incl, count, time_s - 0.5 * window_s, time_s - window_s, time_s,
                             f_nt=f_nt, decl_se_deg=float(se[0]), incl_se_deg=float(se[1]), f_se_nt=float(se[2]))


def trapezoid_weights(count: int) -> np.ndarray:
    """Weights of the trapezoid rule's time average over ``count`` evenly spaced knots (ends
    halved; one knot: itself). They sum to 1 and are exact for a quantity linear in time."""
    if count == 1:
        return np.ones(1)
    weights = np.full(count, 1.0 / (count - 1))
    weights[[0, -1]] *= 0.5
    return weights


def nees_per_step(result: RunResult) -> np.ndarray:
    """Normalised estimation error squared ``e^T P^-1 e`` of the horizontal position at each step
    (e = true minus estimated, east/north metres; P the navigator's own covariance); NaN where
    the navigator gives no covariance. A consistent filter has mean 2 (two degrees of freedom)
    and puts the truth inside its 95 % ellipse (NEES <= CHI2_95_2DOF) 95 % of the time."""
    out = np.full(len(result.est_cov_en_m2), np.nan)
    for k, (ee, en, nn) in enumerate(result.est_cov_en_m2):
        if not all(math.isfinite(v) for v in (ee, en, nn, result.est_lat_deg[k], result.est_lon_deg[k])):
            continue
        e = np.array(enu_offset(result.est_lat_deg[k], result.est_lon_deg[k], result.true_lat_deg[k],
                                result.true_lon_deg[k]))
        cov = np.array([[ee, en], [en, nn]])
        try:
            out[k] = float(e @ np.linalg.solve(cov, e))
        except np.linalg.LinAlgError:
            continue
    return out

"""The flight-controller stand-in: :class:`SitlServer` wires the parts and runs the simulation loop.

Parts (one idea each): :class:`~sitl.fc.vehicle.VehicleSim` (true motion, field, sensors, the
FC's own solution), :class:`~sitl.fc.faults.FaultInjector`, :class:`~sitl.fc.telemetry.Telemetry`
and :class:`~sitl.fc.streams.StreamScheduler` (what is sent, how often),
:class:`~sitl.fc.commands.CommandHandler` and :class:`~sitl.fc.params.FcParams` (what is
obeyed), :class:`~sitl.fc.router.Router` (input, routing), :class:`~sitl.fc.outbox.Outbox`
(output, link faults), :class:`~sitl.fc.lockstep.Stepper` (pacing, lockstep) and
:class:`~sitl.fc.records.Records` (truth.csv, tlog, summary). :class:`sitl.guidance.Guidance`
holds modes, arming and setpoint guidance.

The loop jumps from one event to the next in integer microseconds of simulated time
(sensor samples, field and physics steps, streams, faults, log rows, lockstep boundaries):
wait for the instant (pace), update the command, move the vehicle, run what is due, send.
Paced (``--speedup N``) each instant leaves as its own datagram, and in lockstep at the
boundary. Free-running (``--speedup 0``) nobody is waited for and no wall deadline is kept, so
consecutive instants share datagrams of up to ``MAX_DATAGRAM_BYTES`` (:class:`Outbox`; a
STATUSTEXT or a reply is not held), about seven instants per ``sendto`` and per wake-up of the
reader at the default streams. The links are still read every instant, so a command takes
effect at the same simulated instant as when every instant had its datagram: a ``select(0)``
costs under 1 us (about 1.5 % of the loop), and reading only every fourth instant saved no time
measurable on this machine.
"""
from __future__ import annotations

import math
import selectors
import sys
import threading
import time
from dataclasses import replace

import numpy as np

from companion.params import SPEC_BY_NAME
from sitl.clock import US_PER_S, LockstepGate, Pacer, SimClock
from sitl.fc.commands import CommandHandler
from sitl.fc.config import DEFAULT_OUT, DEFAULT_SPEEDUP, ServerConfig, parse_fault
from sitl.fc.faults import FaultInjector
from sitl.fc.ground_station import FEED_PERIOD_S, SpaceWeatherFeed
from sitl.fc.lockstep import Stepper
from sitl.fc.outbox import Counters, Outbox
from sitl.fc.param_table import ardupilot_params, heading_source_of, px4_params
from sitl.fc.params import FcParams
from sitl.fc.records import Records, format_summary, write_summary
from sitl.fc.router import Router
from sitl.fc.streams import StreamScheduler
from sitl.fc.telemetry import Telemetry
from sitl.fc.vehicle import VehicleSim
from sitl.gifts import gift_line
from sitl.guidance import DIALECTS, PX4, Guidance
from sitl.links import Link, open_link, parse_endpoint
from sitl.mavframe import FrameEncoder
from sitl.scenario import Scenario, ScenarioError, load_scenario
from sitl.world.build import build_truth_field
from sitl.world.magnetic import TruthField

__all__ = ["PHYSICS_STEP_US", "SitlServer"]

PHYSICS_STEP_US = 100_000          # the kinematics step at least every 0.1 s of simulated time
NEVER_US = 1 << 62


class SitlServer:
    """The simulator: ``run()`` until the duration ends or ``request_stop()``; returns the summary."""

    def __init__(self, config: ServerConfig, scenario: Scenario | None = None, truth: TruthField | None = None) -> None:
        config.validate()
        self.config = config
        self.dialect = DIALECTS[config.autopilot]
        base = scenario if scenario is not None else load_scenario(config.scenario)
        extra_faults = tuple(parse_fault(text) for text in config.faults)
        # an open-ended fc_reboot initialises for --init-s, as at the first boot
        faults = tuple(replace(f, duration_s=max(config.init_s, 1e-3)) if f.kind == "fc_reboot"
                       and not math.isfinite(f.duration_s) else f for f in tuple(base.faults) + extra_faults)
        self.scenario = sc = replace(base, faults=faults)
        if any(f.kind == "storm_onset" for f in sc.faults) and not sc.storm.enabled:
            raise ScenarioError("storm_onset fault needs a scenario with [storm] enabled = true")
        truth_full = truth if truth is not None else build_truth_field(sc, config.data_dir, config.expected_duration_s,
                                                                       seed=config.seed)
        self.sysid, self.compid = config.sysid, 1
        rng_sensors, rng_nav, rng_link, rng_gps, rng_att, rng_cal, rng_motion, rng_start = (
            np.random.default_rng(s) for s in np.random.SeedSequence(config.seed).spawn(8))
        self.clock = SimClock()
        self.counters = Counters()
        self._stop = threading.Event()
        self.ready_event = threading.Event()
        cruise = config.cruise_speed_mps
        if cruise is None:
            cruise = float(SPEC_BY_NAME["NAV_SPEED_KMH"].default) / 3.6
        self.guidance = Guidance(self.dialect, sc.vehicle, cruise, config.setpoint_timeout_s)
        self.start_unix_us = int(round(sc.start_posix * US_PER_S))
        self.out = Outbox(FrameEncoder(self.sysid, self.compid), self.clock, self.counters, None, rng_link,
                          self.start_unix_us, batch=config.batch, quiet=config.quiet, hold=config.lockstep)
        self.faults = FaultInjector(sc.faults, self.clock, self.counters, self.out.say)
        self.out.faults = self.faults
        self.vehicle = VehicleSim(sc, truth_full, self.clock, self.faults, rng_sensors, rng_nav, rng_gps,
                                  rng_att=rng_att, rng_cal=rng_cal, rng_motion=rng_motion, rng_start=rng_start,
                                  ins_step_s=config.ins_step_s, wave_roll_deg=config.wave_roll_deg,
                                  wave_pitch_deg=config.wave_pitch_deg)
        self.telemetry = Telemetry(self.out, self.vehicle, self.faults, self.guidance, self.dialect, self.clock,
                                   self.counters, self.sysid)
        self.streams = StreamScheduler(self.telemetry.senders(), config.rates, self.clock, self.out, self.counters)
        self.end_us = int(min(config.duration_s if config.duration_s is not None else math.inf,
                              config.max_sim_s) * US_PER_S)
        self._mag_interval_us = int(US_PER_S / sc.sensors.mag_rate_hz)
        self._imu_interval_us = int(US_PER_S / sc.sensors.imu_rate_hz)
        self._field_interval_us = max(1, int(config.field_step_s * US_PER_S))
        self._log_interval_us = int(US_PER_S / config.log_rate_hz) if config.log_rate_hz > 0 else 0
        # the world's indices as the field is now: a storm_onset fault's quiet hours report a quiet day
        self.gcs_feed = SpaceWeatherFeed(lambda t: self.vehicle.truth.kp(t), lambda t: self.vehicle.truth.symh(t),
                                         self.out, self.sysid, config.space_weather_feed) \
            if config.space_weather_feed else None
        self._next = {"mag": 0, "imu": 0, "field": 0, "log": 0 if self._log_interval_us else NEVER_US,
                      "physics": 0, "init": int(config.init_s * US_PER_S),
                      "gcs": 0 if self.gcs_feed is not None else NEVER_US}
        speedup = config.speedup
        if speedup is None:
            speedup = 0.0 if config.lockstep else DEFAULT_SPEEDUP
        self.pacer = Pacer(speedup)
        # free-run: no wall clock to keep and nobody waited for, so instants share datagrams (Outbox)
        free_run = self.pacer.speedup is None and not config.lockstep
        self.out.coalesce = free_run and config.batch
        self.gate = LockstepGate(config.lockstep_period_s, config.lockstep_timeout_s,
                                 config.lockstep_start_timeout_s, config.lockstep_peer,
                                 config.lockstep_slack) if config.lockstep else None
        table = px4_params if self.dialect is PX4 else ardupilot_params
        self.fc_params = FcParams(table(sysid=self.sysid, cruise_speed_mps=self.guidance.cruise_speed_mps,
                                        setpoint_timeout_s=self.guidance.setpoint_timeout_s,
                                        max_speed_mps=sc.vehicle.max_speed_mps, speedup=speedup,
                                        heading_source=heading_source_of(sc)),
                                  self.out, self.guidance, self.faults, self.counters, sysid=self.sysid,
                                  compid=self.compid, bytewise=self.dialect is PX4,
                                  echo_index=self.dialect is not PX4)
        self.links: list[Link] = self._open_links(config)
        self.records = Records(config, sc.name)
        self.out.links = self.links
        self.out.tlog = self.records.tlog
        self.router = Router(self.links, self.selector, self.out, self.clock, self.counters, sysid=self.sysid,
                             compid=self.compid, routing=config.routing, gate=self.gate)
        self.router.tlog = self.records.tlog
        self.commands = CommandHandler(self.out, self.guidance, self.dialect, self.vehicle, self.streams,
                                       self.telemetry, self.faults, self.clock, self.counters)
        self.router.handlers = {**self.commands.handlers(), **self.fc_params.handlers()}
        self.stepper = Stepper(self.pacer, self.gate, self.router, self.out, self.telemetry, self.clock,
                               self._stop, config.lockstep_peer_pid, config.lockstep_successor,
                               config.lockstep_hang_s)
        self.wall_start = self.wall_end = 0.0
        self.vehicle.set_home()
        self.guidance.home = self.vehicle.home
        self.summary: dict = {}

    def _open_links(self, config: ServerConfig) -> list[Link]:
        outs, masters = tuple(config.outs), tuple(config.masters)
        if not outs and not masters:
            outs = (DEFAULT_OUT,)
        links: list[Link] = []
        self.selector = selectors.DefaultSelector()
        try:
            for text in outs + masters:
                link = open_link(parse_endpoint(text), len(links))
                link.register(self.selector)
                links.append(link)
        except Exception:
            self._close_links(links)
            raise
        return links

    def _close_links(self, links: list[Link]) -> None:
        for link in links:
            try:
                link.close()
            except OSError:
                pass
        self.selector.close()

    # ------------------------------------------------------------------ what tests and tools read
    @property
    def t_us(self) -> int:
        return self.clock.t_us

    @property
    def time_s(self) -> float:
        return self.clock.time_s

    @property
    def state(self):
        """The true vehicle state (:class:`sitl.world.vehicle.VehicleState`)."""
        return self.vehicle.state

    @property
    def params(self) -> dict[str, float]:
        """The flight controller's parameter values, by name (:mod:`sitl.fc.param_table`)."""
        return self.fc_params.values

    @property
    def log_dir(self):
        return self.records.log_dir

    def request_stop(self) -> None:
        """Stop at the next iteration (thread- and signal-safe)."""
        self._stop.set()

    # ------------------------------------------------------------------ the loop
    def _update_faults(self) -> None:
        if self.faults.update():
            self.vehicle.set_storm_scale(self.faults.storm_scale)
        if self.faults.reboot_due is not None:
            self._reboot(self.faults.reboot_due.duration_s)

    def _reboot(self, init_s: float) -> None:
        """An fc_reboot fault: the boot clock restarts at 0 and the autopilot initialises for
        ``init_s`` simulated seconds, disarmed, then enters its ready mode; streams go back to their
        start-up rates. The vehicle (true motion, the FC's navigation solution) and parameters go on."""
        self.faults.reboot_due = None
        self.clock.reboot()
        self.guidance.reboot()
        self.streams.reset()
        if self.gate is not None:
            self.gate.rebooted()
        self.telemetry.last_system_time_us = -1
        self._next["init"] = self.clock.t_us + round(init_s * US_PER_S)

    def _update_command(self) -> None:
        g, v = self.guidance, self.vehicle
        if g.armed and g.behaviour in ("guided", "rtl"):
            lat, lon = v.fc_position()
        else:
            lat = lon = 0.0
        v.cmd = g.command(self.clock.time_s, v.state.course_rad, lat, lon)
        if g.events:
            self.out.relay_events(g)

    def _next_event_us(self) -> int:
        nxt = self._next
        t = min(*nxt.values(), self.faults.next_us, self.stepper.next_us)   # mag, imu, field, log, physics, init, gcs
        t = self.streams.next_due_us(t)
        delayed = self.out.delayed
        if delayed and delayed[0][0] < t:
            t = delayed[0][0]
        return t

    def _run_due(self) -> None:
        now = self.clock.t_us
        nxt = self._next
        v = self.vehicle
        if self.faults.next_us <= now:
            self._update_faults()
        if nxt["init"] <= now:
            nxt["init"] = NEVER_US
            self.guidance.set_ready()
            if self.config.cruise is not None and self.clock.boot0_us == 0:   # at the first boot only
                self.guidance.start_cruise(math.radians(self.config.cruise[0]), self.config.cruise[1])
            self.out.relay_events(self.guidance)
        if nxt["field"] <= now:
            nxt["field"] = now + self._field_interval_us
            v.update_field()
        if nxt["physics"] <= now:
            nxt["physics"] = now + PHYSICS_STEP_US
        if nxt["mag"] <= now:
            nxt["mag"] = now + self._mag_interval_us
            v.sample_mag()
        if nxt["imu"] <= now:
            nxt["imu"] = now + self._imu_interval_us
            v.sample_imu()
        self.streams.run_due(now)
        if nxt["gcs"] <= now:
            nxt["gcs"] = now + int(FEED_PERIOD_S * US_PER_S)
            self.gcs_feed.send(self.clock.time_s)
        if nxt["log"] <= now:
            nxt["log"] = now + self._log_interval_us
            if self.records.truth_log is not None:
                self.records.write_truth(v, self.guidance, self.faults)

    def run(self) -> dict:
        """Run the simulation; returns (and stores in ``summary``) the counters of the run."""
        self.wall_start = time.perf_counter()
        self.pacer.restart(0)
        self.ready_event.set()
        if not self.config.quiet:
            self._print_banner()
        stepper, clock, out = self.stepper, self.clock, self.out
        try:
            self._update_faults()
            while not self._stop.is_set():
                t_next = self._next_event_us()
                if t_next > self.end_us:
                    break
                stepper.pace(t_next)
                self._update_command()
                self.vehicle.advance(t_next)
                clock.t_us = t_next
                self._run_due()
                out.flush(release=False)    # sent now, or in lockstep at the boundary (below)
                if stepper.next_us <= clock.t_us:
                    stepper.wait_at_boundary()
        finally:
            self.wall_end = time.perf_counter()
            self._finish()
        return self.summary

    def _print_banner(self) -> None:
        c = self.config
        links = ", ".join(f"{link.endpoint} (local {link.local_address[0]}:{link.local_address[1]})"
                          for link in self.links)
        pace = "unlimited" if self.pacer.speedup is None else f"{self.pacer.speedup:g}x"
        print(f"fcmpc-sitl: scenario {self.scenario.name}, {self.dialect.name} boat sysid {self.sysid}, "
              f"links {links}, speed-up {pace}{', lockstep %gs' % c.lockstep_period_s if c.lockstep else ''}, "
              f"records {self.log_dir if self.records.enabled else 'off'}", file=sys.stderr, flush=True)
        gifted = gift_line(self.scenario)
        if gifted:
            print(f"fcmpc-sitl: {gifted}", file=sys.stderr, flush=True)

    def _finish(self) -> None:
        if self.out.hold:               # lockstep: what was held since the last boundary (a run ending off one)
            self.out.flush(release=True)
        self.out.send_coalesced()
        self.records.finish(self.vehicle, self.guidance, self.faults)
        self._close_links(self.links)
        wall = max(self.wall_end - self.wall_start, 1e-9)
        sim = self.clock.time_s
        tx = self.counters.get("tx_messages", 0)
        state = self.vehicle.state
        summary = {
            "scenario": self.scenario.name, "autopilot": self.dialect.name, "seed": self.config.seed,
            "sim_s": round(sim, 3), "wall_s": round(wall, 3), "speedup": round(sim / wall, 1),
            "tx_messages": tx, "tx_msgs_per_wall_s": round(tx / wall, 1),
            "tx_bytes": sum(link.tx_bytes for link in self.links),
            "tx_dropped_socket": sum(link.tx_dropped for link in self.links),
            "mode": self.guidance.mode, "armed": self.guidance.armed,
            "lat_deg": state.lat_deg, "lon_deg": state.lon_deg, "distance_m": state.distance_m,
            "counters": dict(sorted({**self.counters, **self.guidance.counters}.items())),
            "tx_by_type": dict(sorted(self.out.tx_by_type.items())),
            "rx_by_type": dict(sorted(self.router.rx_by_type.items())),
            "peers": [f"{s}/{c}" for s, c in self.router.peers],
            "log_dir": str(self.log_dir) if self.records.enabled else None,
        }
        if self.gate is not None:
            summary.update(self.gate.stats())
            summary.update(self.stepper.stats())
        self.summary = summary
        path = self.config.summary_json
        if path is None and self.records.enabled:
            path = str(self.log_dir / "summary.json")
        write_summary(summary, path)
        if not self.config.quiet:
            print(format_summary(summary), file=sys.stderr, flush=True)

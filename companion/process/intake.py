"""Samples in: the flight controller's MAVLink sensors and a ``--sensors`` source, on message time.

Sensor sources (``--sensors SPEC``, :func:`companion.io.sensors.make_source`)
    Without it the flight controller's MAVLink streams are the sensors. With it the source
    (``i2c:/dev/i2c-1``, ``dronecan:can0``, ``replay:log.bin?speed=1``, ``i2c:1+ubx:/dev/ttyS0``,
    ...) is opened at start (an error: exit code 2) and polled without waiting from the run loop;
    its samples take the same path as MAVLink's. The kinds it provides replace the flight
    controller's: its magnetometer makes the companion ignore RAW_IMU/SCALED_IMU/HIGHRES_IMU
    magnetometers (two magnetometers are never mixed), its attitude replaces ATTITUDE; a kind it
    lacks (DroneCAN: attitude) still comes from the flight controller, as do heartbeat, mode,
    arming and the INS position. Its GPS is start-up and record only.
    Time: a direct source stamps with the host monotonic clock, a replay with log time, the
    navigation runs on message time. A sample's time is mapped with an offset learned at
    reception, offset = message time now - source time of the newest sample of the batch, kept
    while it moves by less than SOURCE_RESYNC_S and learned again when it jumps (an FC reboot, a
    replay faster than message time). This assumes the transport latency on both paths is
    negligible against the 0.5 s attitude-matching window; the flight controller's message
    clock only advances in steps (its message rate), so the mapping jitters by up to one
    message interval. Before the first flight-controller time stamp samples are dropped
    (counted in the summary). A source that stops delivering (device gone, replay ended) goes
    stale like a silent MAVLink stream and triggers the same failsafe; a STATUSTEXT names the
    source once.
"""
from __future__ import annotations

import math
import sys
from dataclasses import replace

from companion.io.link.clock import MessageClock
from companion.io.link import mavlink
from companion.io.sensors.base import SampleKind, SensorError, SensorSource, StreamEnd
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.magnetometer import AttitudeState, MagProcessor
from companion.process.mission_state import MissionState
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["SOURCE_RESYNC_S", "SampleIntake", "SourceTimeMap", "source_kinds"]

SOURCE_RESYNC_S = 1.0             # --sensors: re-learn the source-to-message-time offset beyond this jump
_MAG, _ATT, _GPS, _IMU = SampleKind.MAG, SampleKind.ATTITUDE, SampleKind.GPS, SampleKind.IMU

def source_kinds(source: SensorSource) -> frozenset:
    """The sample kinds (MAG, ATTITUDE, GPS) ``source`` provides (:attr:`SensorSource.provides`,
    declared by each source type), which the FC's then do not."""
    return frozenset(source.provides)


class SourceTimeMap:
    """Source time -> message time: ``t_msg = t_source + offset``.

    ``offset`` = message time now - source time of the newest sample, learned on the first
    batch and again whenever that quantity moves by more than ``resync_s`` (a jump of either
    clock). Assumes negligible transport latency on both paths.

    >>> m = SourceTimeMap()
    >>> [round(t, 3) for t in m.map(100.0, [5000.0, 5000.1])]   # the newest sample is "now"
    [99.9, 100.0]
    >>> [round(t, 3) for t in m.map(100.25, [5000.3])]          # within 1 s: offset kept
    [100.2]
    >>> [round(t, 3) for t in m.map(250.0, [5000.4])]           # a jump: learned again
    [250.0]
    >>> m.resyncs
    2
    """

    def __init__(self, resync_s: float = SOURCE_RESYNC_S) -> None:
        self.resync_s = resync_s
        self.offset_s: float | None = None
        self.resyncs = 0

    def map(self, now_msg_s: float, source_times: list[float]) -> list[float]:
        finite = [t for t in source_times if math.isfinite(t)]
        if finite:
            candidate = now_msg_s - max(finite)
            if self.offset_s is None or abs(candidate - self.offset_s) > self.resync_s:
                self.offset_s = candidate
                self.resyncs += 1
        off = self.offset_s if self.offset_s is not None else math.nan
        return [t + off for t in source_times]


class SampleIntake:
    """Samples of either path into the magnetometer pipeline; their validity and ages."""

    def __init__(self, source: SensorSource | None, spec: str | None, decoder: MavlinkDecoder, mag: MagProcessor,
                 msg_clock: MessageClock, settings: Settings, state: MissionState, voice: Voice) -> None:
        """``source``: the --sensors source built from ``spec`` (None: MAVLink only)."""
        self.source = source
        self.spec = spec
        self.decoder = decoder
        self.mag = mag
        self.msg_clock = msg_clock
        self.settings = settings
        self.mission_state = state
        self.voice = voice
        self.source_kinds = source_kinds(source) if source is not None else frozenset()
        self.source_time = SourceTimeMap()
        self.source_open = False
        self.dropped_no_clock = 0
        self.source_last_rx = math.nan      # message time of the newest mapped source sample
        self.source_silent_said = False
        self.source_ended = ""
        self.source_problem: dict[str, str] = {}
        self.last_valid: dict[SampleKind, float] = {}   # message time of the last valid sample per kind
        self.invalid_mag = 0
        self.last_gps = None
        self.last_fix = None                # the last valid 3D fix (last_gps may since say no fix)
        self.messages_from_fc = 0           # every message of the flight controller followed

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: no sample is valid on the new one yet."""
        self.last_valid.clear()

    # ------------------------------------------------------------------ the source's life
    def open_source(self) -> None:
        if self.source is not None and not self.source_open:
            self.source.open()          # SensorError: main() exits with 2 before anything else opens
            self.source_open = True

    def close_source(self) -> None:
        if self.source is not None and self.source_open:
            self.source_open = False
            try:
                self.source.close()
            except (OSError, SensorError) as err:  # pragma: no cover - the device is gone anyway
                print(f"fcmpc-companion: closing {self.source.name}: {err}", file=sys.stderr)

    # ------------------------------------------------------------------ samples
    def decode(self, msg) -> bool:
        """The flight controller's samples in ``msg`` (kinds --sensors provides are ignored); True
        when the decoder replaced a magnetometer stream by a preferred one (to be turned off)."""
        self.messages_from_fc += 1
        decoder = self.decoder
        kinds = self.source_kinds   # hashing a SampleKind is a Python call: skipped when empty
        for sample in decoder.decode(msg):
            if not kinds or sample.kind not in kinds:
                self.use(sample, sample.time_s, decoder.rates)
        return bool(decoder.superseded)

    def use(self, sample, t: float, rates: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """One sample (MAVLink or --sensors) at message time ``t`` into the magnetometer pipeline."""
        mag = self.mag
        kind = sample.kind
        if kind is _MAG:
            if sample.flags:
                self.invalid_mag += 1
                if sample.stale_since_s < self.last_valid.get(_MAG, -math.inf):
                    # judged frozen: its repeats since it froze were not fresh either, so the
                    # failsafe's age counts from the freeze (HOLD at the judgement, not 2 s later)
                    self.last_valid[_MAG] = sample.stale_since_s
            else:
                self.last_valid[_MAG] = t
                mag.add_mag(t, sample.mag_body_nt)
        elif kind is _ATT:
            if not sample.flags:
                att = AttitudeState.from_body_rates(t, sample.roll_rad, sample.pitch_rad, sample.yaw_rad, *rates)
                if mag.add_attitude(att):
                    self.last_valid[_ATT] = t
        elif kind is _IMU:   # 10 Hz, before the 1 Hz GPS
            if not sample.flags:
                mag.add_specific_force(t, sample.accel_body_mps2, sample.gyro_body_radps)
        elif kind is _GPS:
            self.last_gps = sample if t == sample.time_s else replace(sample, time_s=t)
            if sample.valid and sample.has_3d_fix:
                self.last_fix = self.last_gps

    def poll(self) -> None:
        """Periodic hook for ``--sensors``: take what the source has now (never waits)."""
        source = self.source
        if source is None or not self.source_open:
            return
        try:
            samples = source.poll(0.0)
        except SensorError as err:   # sources count errors instead of raising; be safe anyway
            samples = []
            self.source_problem["mag"] = str(err)
        if samples:
            if not self.msg_clock.started:   # no message time to put them on yet
                self.dropped_no_clock += len(samples)
                return
            times = self.source_time.map(self.msg_clock.now_s, [s.time_s for s in samples])
            rates = (0.0, 0.0, 0.0)
            fresh = False
            for sample, t in zip(samples, times):
                if isinstance(sample, StreamEnd):
                    self.source_ended = sample.detail or "end of stream"
                    continue
                if sample.kind is SampleKind.IMU:
                    rates = sample.gyro_body_radps
                    continue
                if sample.kind not in self.source_kinds:
                    continue
                if sample.flags and sample.kind is _MAG:
                    self.source_problem["mag"] = f"{source.name}: flagged {sample.flags!r}"
                self.use(sample, t, rates)
                if not sample.flags:
                    fresh = True
                    self.source_last_rx = t   # batch order is time order; after an FC reboot, the new base
            if fresh and self.source_silent_said and not self.source_ended:
                self.source_silent_said = False
                self.source_problem.pop("mag", None)
                self.voice.say(f"FcMPC: sensor source {source.name} delivering again", mavlink.MAV_SEVERITY_NOTICE)
        self._check_silence()

    def _check_silence(self) -> None:
        """Say once that the source stopped (ended, or nothing for longer than the staleness timeout)."""
        if self.source_silent_said or not self.msg_clock.started:
            return
        comp, now = self.settings.comp, self.msg_clock.now_s
        source = self.source
        why = ""
        if self.source_ended or source.finished:
            why = f"ended ({self.source_ended or 'finished'})"
        else:
            timeout = min(comp.mag_timeout_s, comp.att_timeout_s) if _ATT in self.source_kinds else comp.mag_timeout_s
            since = self.source_last_rx if math.isfinite(self.source_last_rx) else self.mission_state.fc_detected_at
            if math.isfinite(since) and now - since > timeout:
                err = source.stats.last_error
                why = f"silent for {now - since:.1f} s" + (f" (last error: {err})" if err else "")
        if why:
            self.source_silent_said = True
            self.source_problem["mag"] = f"sensor source {source.name} {why}"
            self.voice.say(f"FcMPC: sensor source {source.name} {why}"[:200], mavlink.MAV_SEVERITY_CRITICAL)

    # ------------------------------------------------------------------ ages
    def age(self, kind: SampleKind, now: float) -> float:
        """Message-time age of the last valid sample of a kind (infinite if none yet)."""
        last = self.last_valid.get(kind)
        return math.inf if last is None else now - last

    def summary(self) -> dict | None:
        source = self.source
        if source is None:
            return None
        return {"spec": self.spec, "name": source.name,
                "kinds": sorted(k.value for k in self.source_kinds),
                "samples": source.stats.samples, "flagged": source.stats.flagged,
                "read_errors": source.stats.read_errors, "last_error": source.stats.last_error,
                "dropped_no_fc_clock": self.dropped_no_clock, "time_resyncs": self.source_time.resyncs,
                "time_offset_s": self.source_time.offset_s, "ended": self.source_ended}

"""The stand-in's stream scheduler: which message goes out how often, in simulated time.

Defaults are ArduPilot-like (``DEFAULT_RATES_HZ``, the SRn_* of a telemetry port); ``--rate
NAME:HZ`` changes a default, and a client changes a rate with MAV_CMD_SET_MESSAGE_INTERVAL
(interval in us; -1 off, 0 default) or REQUEST_DATA_STREAM (ArduPilot's groups of messages,
``DATA_STREAM_GROUPS``). A stream due at ``next_us`` is sent and re-armed one interval later;
after a rate change or a long step it is re-armed from now, so no burst makes up for lost time.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import US_PER_S, SimClock
from sitl.guidance import MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED

__all__ = ["DATA_STREAM_GROUPS", "DEFAULT_RATES_HZ", "MAX_RATE_HZ", "STREAM_BY_ID", "STREAM_IDS", "Stream",
           "StreamScheduler"]

MAX_RATE_HZ = 1000.0

# Messages the simulator can stream, by name: (message id, default rate in Hz).
# ArduPilot-like defaults (SRn_* of a telemetry port); HEARTBEAT/SYSTEM_TIME/SYS_STATUS at 1 Hz.
DEFAULT_RATES_HZ = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "SYSTEM_TIME": 1.0,
    "RAW_IMU": 10.0,
    "SCALED_IMU": 10.0,
    "ATTITUDE": 10.0,
    "GLOBAL_POSITION_INT": 5.0,
    "GPS_RAW_INT": 5.0,
    "LOCAL_POSITION_NED": 5.0,
    "HIGHRES_IMU": 0.0,
    "VFR_HUD": 0.0,
    "HOME_POSITION": 0.0,
    "EXTENDED_SYS_STATE": 0.0,
}
STREAM_IDS = {
    "HEARTBEAT": 0, "SYS_STATUS": 1, "SYSTEM_TIME": 2, "GPS_RAW_INT": 24, "SCALED_IMU": 26, "RAW_IMU": 27,
    "ATTITUDE": 30, "LOCAL_POSITION_NED": 32, "GLOBAL_POSITION_INT": 33, "VFR_HUD": 74, "HIGHRES_IMU": 105,
    "HOME_POSITION": 242, "EXTENDED_SYS_STATE": 245,
}
STREAM_BY_ID = {v: k for k, v in STREAM_IDS.items()}
# REQUEST_DATA_STREAM groups (ArduPilot's assignment of messages to MAV_DATA_STREAM_*).
DATA_STREAM_GROUPS = {
    1: ("RAW_IMU", "SCALED_IMU"),                      # RAW_SENSORS
    2: ("SYS_STATUS", "GPS_RAW_INT"),                  # EXTENDED_STATUS
    3: (), 4: (),                                      # RC_CHANNELS, RAW_CONTROLLER
    6: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),  # POSITION
    10: ("ATTITUDE",),                                 # EXTRA1
    11: ("VFR_HUD",),                                  # EXTRA2
    12: ("SYSTEM_TIME",),                              # EXTRA3
}
DATA_STREAM_GROUPS[0] = tuple(name for group in DATA_STREAM_GROUPS.values() for name in group)


class Stream:
    """One periodic message: its interval and next due time in simulated us, and its sender."""

    __slots__ = ("name", "interval_us", "next_us", "send")

    def __init__(self, name: str, rate_hz: float, send) -> None:
        self.name = name
        self.send = send
        self.next_us = 0
        self.interval_us = 0
        self.set_rate(rate_hz, 0)

    def set_rate(self, rate_hz: float, now_us: int) -> None:
        if rate_hz <= 0.0:
            self.interval_us = 0
            self.next_us = 1 << 62
        else:
            self.interval_us = max(int(round(US_PER_S / min(rate_hz, MAX_RATE_HZ))), 1)
            self.next_us = now_us


class StreamScheduler:
    """The streams by name, their rates, and the MAVLink requests that change them."""

    def __init__(self, senders: dict, rate_overrides: tuple[str, ...], clock: SimClock, out, counters) -> None:
        rates = dict(DEFAULT_RATES_HZ)
        for text in rate_overrides:
            name, _, hz = text.partition(":")
            if name.upper() not in rates:
                raise ValueError(f"--rate {text!r}: unknown message (streams: {', '.join(rates)})")
            rates[name.upper()] = float(hz)
        self.default_rates = dict(rates)
        self.streams = {name: Stream(name, rates[name], senders[name]) for name in DEFAULT_RATES_HZ}
        self._on: list[Stream] = []     # the streams with a rate, in the order above (see _rates_changed)
        self._rates_changed()
        self.clock = clock
        self.out = out
        self.counters = counters

    def reset(self) -> None:
        """After a reboot: every stream back to its start-up rate (requested intervals are not kept)."""
        for name, stream in self.streams.items():
            stream.set_rate(self.default_rates[name], self.clock.t_us)
        self._rates_changed()

    def _rates_changed(self) -> None:
        """After any rate change: the loop's two scans per instant skip the streams that are off
        (due never, they could neither be the next event nor be sent)."""
        self._on = [stream for stream in self.streams.values() if stream.interval_us]

    def next_due_us(self, t_us: int) -> int:
        """The earliest due time of any stream, or ``t_us`` when none is earlier."""
        for stream in self._on:
            if stream.next_us < t_us:
                t_us = stream.next_us
        return t_us

    def run_due(self, now: int) -> None:
        for stream in self._on:
            if stream.next_us <= now:
                stream.next_us += stream.interval_us
                if stream.next_us <= now:   # after a rate change or a long step: no burst
                    stream.next_us = now + stream.interval_us
                stream.send()

    def set_message_interval(self, msg_id: float, interval_us: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL: the MAV_RESULT."""
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)) or int(msg_id) not in STREAM_BY_ID:
            self.counters.add("interval_unsupported")
            return MAV_RESULT_UNSUPPORTED
        stream = self.streams[STREAM_BY_ID[int(msg_id)]]
        if interval_us == -1:
            rate = 0.0
        elif interval_us == 0:
            rate = self.default_rates[stream.name]
        elif interval_us < 1000:
            return MAV_RESULT_DENIED
        else:
            rate = US_PER_S / interval_us
        stream.set_rate(rate, self.clock.t_us)
        self._rates_changed()
        return MAV_RESULT_ACCEPTED

    def get_message_interval(self, msg_id: float) -> int:
        """MAV_CMD_GET_MESSAGE_INTERVAL: answers MESSAGE_INTERVAL (0 = not available)."""
        if not math.isfinite(msg_id) or int(msg_id) not in STREAM_BY_ID:
            self.out.emit(mavlink.MAVLink_message_interval_message, int(msg_id) if math.isfinite(msg_id) else 0, 0)
            return MAV_RESULT_ACCEPTED
        stream = self.streams[STREAM_BY_ID[int(msg_id)]]
        self.out.emit(mavlink.MAVLink_message_interval_message, int(msg_id), stream.interval_us or -1)
        return MAV_RESULT_ACCEPTED

    def on_request_data_stream(self, msg) -> None:
        names = DATA_STREAM_GROUPS.get(msg.req_stream_id)
        if names is None:
            self.counters.add("data_stream_unknown")
            return
        rate = float(msg.req_message_rate) if msg.start_stop else 0.0
        for name in names:
            self.streams[name].set_rate(rate, self.clock.t_us)
        self._rates_changed()

"""``fcmpc-companion --sensors``: a DroneCAN magnetometer instead of the flight controller's.

The companion runs its real loop (:meth:`CompanionApp.run`) in a thread; a pymavlink peer on
UDP plays the flight controller (heartbeat, SYSTEM_TIME, ATTITUDE and a RAW_IMU carrying a
*different* field), and a second dronecan node on python-can's virtual bus publishes real
MagneticFieldStrength2 frames. Message time advances by a fixed step per burst, whatever the wall
time a step takes, and the CAN driver's host clock is that message time (the companion maps the
host-stamped CAN samples onto message time): a loaded machine slows the test, never changes it.
"""
from __future__ import annotations

import itertools
import math
import os
import signal
import threading
import time
import types

import can.interfaces.virtual
import dronecan
import dronecan.driver.python_can
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.app import CompanionApp, State, build_parser, main, options_from_args  # noqa: E402
from companion.io.link import mavlink  # noqa: E402
from companion.io.sensors.base import SampleKind  # noqa: E402
from tests.lockstep import HANG_S  # noqa: E402
from tests.ports import free_port  # noqa: E402

# dronecan's own driver still passes python-can the deprecated 'bustype' keyword.
pytestmark = pytest.mark.filterwarnings("ignore:The 'bustype' argument is deprecated:DeprecationWarning")

HOLD_DISARMED = dict(type=11, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode=1, custom_mode=4,
                     system_status=3, mavlink_version=3)
ARMED_GUIDED = dict(HOLD_DISARMED, base_mode=mavlink.MAV_MODE_FLAG_SAFETY_ARMED
                    | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode=15, system_status=4)

CAN_FIELD_GA = (0.2314, 0.0508, -0.5313)          # body = NED: the FC reports the vehicle level, yaw 0
CAN_D_DEG = math.degrees(math.atan2(CAN_FIELD_GA[1], CAN_FIELD_GA[0]))                       # 12.38
CAN_I_DEG = math.degrees(math.atan2(CAN_FIELD_GA[2], math.hypot(CAN_FIELD_GA[0], CAN_FIELD_GA[1])))  # -65.97
FC_FIELD_MG = (100, -200, 400)                    # the FC's own magnetometer: D = -63.4, I = +60.8

_channels = itertools.count()


class Rig:
    """The companion's run loop in a thread, a MAVLink FC peer and a DroneCAN magnetometer node."""

    def __init__(self, tmp_path, channel: str) -> None:
        port = free_port()
        self.channel = channel
        self.fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
        # this FC peer serves no parameters: declare the heading instead of waiting for EK3_SRC1_YAW
        (tmp_path / "p.parm").write_text("COMP_HEADING_SRC 1\n")
        args = build_parser().parse_args([
            "--connect", f"udpout:127.0.0.1:{port}", "--params", str(tmp_path / "p.parm"),
            "--log-dir", str(tmp_path / "log"), "--quiet", "--no-tlog", "--startup-s", "0.5",
            "--sensors", f"dronecan:virtual:{channel}"])
        self.app = CompanionApp(options_from_args(args))
        self.can = dronecan.make_node(channel, node_id=42, bustype="virtual", bitrate=1_000_000)
        self.thread = threading.Thread(target=self.app.run, name="companion", daemon=True)
        self.received: list = []
        self.heartbeat = HOLD_DISARMED
        self.msg_t = 1.0
        self.n = 0
        self.can_sent = 0

    def start(self) -> None:
        self.thread.start()
        # the companion speaks first (udpout); its CAN node is open by then
        assert self.fc.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0) is not None

    def stop(self) -> None:
        self.app.request_stop()
        self.thread.join(5.0)
        self.can.close()
        self.fc.close()

    def publish_can(self) -> None:
        j = 0.0005 * (self.n % 3 - 1)              # a little noise: a constant reading is flagged STUCK
        ga = [CAN_FIELD_GA[0] + j, CAN_FIELD_GA[1] - j, CAN_FIELD_GA[2]]
        self.can.broadcast(dronecan.uavcan.equipment.ahrs.MagneticFieldStrength2(sensor_id=0, magnetic_field_ga=ga))
        self.can_sent += 1

    def step(self, dt: float | None = None, can_on: bool = True, wall_s: float = 0.01) -> None:
        """One FC message burst (message time +dt; None: ``wall_s``, the rest that follows it) and a CAN
        frame. The CAN driver stamps what it receives with this message time (:func:`rig`), so a step
        is the same whatever the wall time it takes on a loaded machine."""
        self.n += 1
        self.msg_t += wall_s if dt is None else dt
        ms = int(self.msg_t * 1000)
        mav = self.fc.mav
        mav.heartbeat_send(**self.heartbeat)
        mav.system_time_send(0, ms)
        mav.attitude_send(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        k = self.n % 3 - 1
        mav.raw_imu_send(ms * 1000, 0, 0, -1000, 0, 0, 0, FC_FIELD_MG[0] + k, FC_FIELD_MG[1] - k, FC_FIELD_MG[2])
        if can_on:
            self.publish_can()
        time.sleep(wall_s)
        self.drain()

    def drain(self) -> None:
        while (msg := self.fc.recv_match(blocking=False)) is not None:
            self.received.append(msg)

    def texts(self) -> str:
        # long texts arrive as several 50-character STATUSTEXT chunks
        return "".join(m.text for m in self.received if m.get_type() == "STATUSTEXT")

    def named(self, name: str) -> list[float]:
        return [m.value for m in self.received if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == name]

    def until(self, condition, limit_wall_s: float = HANG_S, **step) -> None:   # a hang guard, not a pace
        deadline = time.monotonic() + limit_wall_s
        while not condition():
            assert time.monotonic() < deadline, f"timed out; companion state {self.app.state}, " \
                                                f"events {self.app.voice.events[-5:]}"
            self.step(**step)

    def fly(self) -> None:
        """Start-up on the CAN magnetometer, then armed in GUIDED: the mission's first step."""
        self.until(lambda: self.app.state == State.READY)
        self.heartbeat = ARMED_GUIDED
        self.until(lambda: self.named("FC_D") and self.named("FC_I"))


@pytest.fixture
def rig(tmp_path, monkeypatch: pytest.MonkeyPatch):
    # dronecan's python-can driver calls flush_tx_buffer() after each send, which the
    # virtual bus does not implement (see /work/shared/PACKAGES.md).
    monkeypatch.setattr(can.interfaces.virtual.VirtualBus, "flush_tx_buffer", lambda self: None, raising=False)
    r = Rig(tmp_path, f"fcmpc-app-{os.getpid()}-{next(_channels)}")
    # the companion stamps a CAN frame with the host's monotonic clock when its driver takes it: here
    # that clock is the rig's message time, so the stamps and message time agree however long a step
    # takes. With the wall's clock a loaded machine (steps of more than their 10 ms) put the samples
    # up to the 1 s the companion's mapping tolerates away from message time, past the attitude's
    # 0.5 s window: left out, a step postponed for want of samples, the test timed out (1 of 5 runs)
    monkeypatch.setattr(dronecan.driver.python_can, "time",
                        types.SimpleNamespace(monotonic=lambda: r.msg_t, time=time.time, sleep=time.sleep))
    r.start()
    yield r
    r.stop()


def test_dronecan_magnetometer_replaces_the_fcs(rig: Rig) -> None:
    app = rig.app
    # before the flight controller's first time stamp there is no message time: dropped, counted
    for _ in range(3):
        rig.publish_can()
    deadline = time.monotonic() + 30.0      # a hang guard: the loop ends on the event
    while app.intake.dropped_no_clock < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert app.intake.dropped_no_clock == 3

    rig.fly()
    d, i = app.mag.last_di
    # float16 on the wire: about 24 nT at 0.5 G, a few hundredths of a degree
    assert d == pytest.approx(CAN_D_DEG, abs=0.2) and i == pytest.approx(CAN_I_DEG, abs=0.2)
    assert rig.named("FC_D")[0] == pytest.approx(CAN_D_DEG, abs=0.2)      # the telemetry the GCS sees
    assert rig.named("FC_I")[0] == pytest.approx(CAN_I_DEG, abs=0.2)
    # the FC's RAW_IMU magnetometer (D = -63 deg) never reached the pipeline: every sample
    # processed came from CAN, none was a spike or non-finite; on a loaded machine (parallel CI
    # workers) some wait longer than the attitude's age limit and are left out (44 of 79 once)
    st = app.mag.stats
    assert 10 < st.samples <= rig.can_sent - 3 and st.accepted >= 10 and st.spikes == 0 and st.non_finite == 0
    assert st.accepted + st.no_attitude + st.paused >= st.samples - 2
    assert app.intake.invalid_mag == 0
    # the mapped CAN sample times sit on message time (a wrong mapping is off by the CAN clock's
    # epoch; under load the last sample lags the FC's newest message by up to a second or two)
    assert abs(app.now - app.intake.last_valid[SampleKind.MAG]) < 5.0
    summary = app.summary()["sensors"]
    assert summary["kinds"] == ["mag"] and summary["dropped_no_fc_clock"] == 3 and summary["samples"] >= 10
    assert "FAILSAFE" not in rig.texts()


def test_can_magnetometer_going_silent_is_a_failsafe(rig: Rig) -> None:
    app = rig.app
    rig.fly()
    assert app.state == State.RUNNING and not app.failsafe_active
    rig.drain()
    rig.received.clear()
    # message time and the newest valid sample as the app saw them when it declared the failsafe
    # (in its own thread): not the event text's time, printed to 0.1 s, nor last_valid read
    # after a sleep, which raced the app's thread still taking the last CAN frames
    seen_at_failsafe: list[tuple[float, float]] = []
    say = app.voice.say

    def spy(text: str, *args, **kwargs):
        if "FAILSAFE" in text and not seen_at_failsafe:
            seen_at_failsafe.append((app.now, app.intake.last_valid[SampleKind.MAG]))
        return say(text, *args, **kwargs)

    app.voice.say = spy
    # the CAN node stops; the FC keeps talking, message time runs 5x faster than the wall
    def holds() -> list:
        return [m for m in rig.received if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE]

    # until what is judged below has arrived: the texts (long ones in several chunks) and the mode
    # command, which reach the rig in no fixed order with the failsafe's first words (1 of 5 loaded runs)
    rig.until(lambda: "FcMPC FAILSAFE" in rig.texts() and "mag: no valid magnetometer sample" in rig.texts()
              and "FcMPC: sensor source" in rig.texts() and holds(), dt=0.05, can_on=False)
    t_fs, last = seen_at_failsafe[0]
    timeout = app.settings.comp.mag_timeout_s
    assert len([e for e in app.voice.events if "FcMPC FAILSAFE" in e]) == 1
    # stale strictly after COMP_MAG_TMO_S, judged at the next control tick (COMP_SP_RATE_HZ)
    assert timeout < t_fs - last <= timeout + 1.0 / app.settings.comp.setpoint_rate_hz + 0.1
    texts = rig.texts()
    assert "mag: no valid magnetometer sample" in texts
    assert f"sensor source dronecan@virtual:{rig.channel} silent" in texts
    assert texts.count("FcMPC: sensor source") == 1                                     # said once
    assert holds()[0].param2 == 4                                                       # Rover HOLD
    # it comes back: samples flow again, the source says so
    rig.until(lambda: "delivering again" in rig.texts(), can_on=True)


@pytest.mark.parametrize("spec,expected", [
    ("i2c:/dev/i2c-99", "cannot open I2C bus /dev/i2c-99"),
    ("bogus:thing", "expected one of i2c:..., ubx:..., dronecan:..., replay:..."),
    ("dronecan:virtual:x?colour=blue", "unknown option(s) ['colour']"),
])
def test_bad_source_exits_with_2(tmp_path, capsys, spec: str, expected: str) -> None:
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        code = main(["--connect", f"udpout:127.0.0.1:{free_port()}", "--log-dir", str(tmp_path), "--quiet",
                     "--no-tlog", "--sensors", spec])
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("fcmpc-companion: ") and expected in err

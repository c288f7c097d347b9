"""The companion against real ArduPilot Rover SITL (motorboat): what the real-firmware issue names.

Every test starts ``ardurover`` in its own folder with its own ``-I`` instance, a monitor on
SERIAL0 (SIMSTATE is the truth) and the companion on SERIAL1, and waits on events (texts,
heartbeats, firmware time), never on sleeps.
"""
from __future__ import annotations

import math
import os
import signal

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.link import MessageClock
from companion.io.sensors.mag_units import highres_nt_per_unit, mag_messages
from companion.io.sensors.mavlink_source import MavlinkDecoder
from fcmpc.firmware.compass import ARDUPILOT_REAL, ardupilot_compass_params, calibrate_fixed_yaw
from tests.firmware.conftest import assert_forward_on as _assert_forward_on
from tests.firmware.conftest import moving_pairs as _moving

GUIDED, HOLD = 15, 4
WALL_S = 300.0          # generous: a loaded 2-core machine runs SITL far below its nominal speed-up


@pytest.mark.parametrize("probes, compass", [((45.0, 315.0), "ideal"), ((225.0, 135.0), "real")],
                         ids=["NE-SE, SITL's perfect compass", "SW-NW, a real compass and the companion's circles"])
def test_start_up_ends_and_every_quadrant_is_driven_forward(rig_factory, probes, compass):
    """SITL's own compass is noise-free (SIM_MAG_RND 0); a real one is not (log171's hard and soft
    iron, noise, a CompassMot result's motor interference: ``fcmpc.firmware.compass``), calibrated by
    ArduPilot's fixed-yaw calibration as a boat's user does, which learns its offsets only. With the
    real one the companion flies its calibration circles first (COMP_CAL_TURNS 1): without them every
    period after the first turn was excluded (the fix would jump 530-640 km). With either, start-up
    must end; then the two probing moves (theta 45/315: courses NE, SE; theta 225/135: SW, NW) are
    driven forward."""
    rig = rig_factory("quadrants", params=ardupilot_compass_params(compass))
    circles = {}
    if compass == "real":
        calibrate_fixed_yaw(rig.monitor)
        circles = {"COMP_CAL_TURNS": 1}
    rig.start_companion(NAV_DEST_LAT=31.0, NAV_DEST_LON=154.0, NAV_PERIOD_S=60.0,
                        NAV_PROBE1_DEG=probes[0], NAV_PROBE2_DEG=probes[1], **circles)
    mon = rig.monitor
    mon.pump(rig.said("phase probe2"), WALL_S, "second probing move")
    t1 = mon.texts_matching("phase probe1", 191)[0][0]
    t2 = mon.texts_matching("phase probe2", 191)[0][0]
    mon.pump(lambda m: m.time_s >= t2 + 60.0, WALL_S, "end of the second probe")
    assert not mon.texts_matching("stuck", 191), "a quiet compass was judged stuck"
    assert not mon.texts_matching("target not received", 1), "a setpoint gap: ArduPilot stopped"
    courses = [(90.0 - p) % 360.0 for p in probes]
    _assert_forward_on(mon.truth, t1 + 15.0, t2, courses[0])
    _assert_forward_on(mon.truth, t2 + 15.0, t2 + 58.0, courses[1])
    if compass == "real":
        assert mon.texts_matching("magnetometer calibrated", 191)
        assert not mon.texts_matching("implausible", 191), mon.texts_matching("implausible", 191)


def test_a_boats_compass_calibration_learns_the_hard_iron_only(rig_factory):
    """The real compass calibrated as a boat's user does (MAV_CMD_FIXED_MAG_CAL_YAW at the true
    heading, GPS position, ArduPilot's own field tables): ArduPilot's offsets come within 10 mGauss
    of the installation's hard iron (its soft iron and noise keep them from exact), and nothing learns
    the soft iron, which the companion then meets in flight."""
    rig = rig_factory("calibration", params=ardupilot_compass_params("real"))
    words = calibrate_fixed_yaw(rig.monitor)
    learnt = rig.monitor.read_params(("COMPASS_OFS_X", "COMPASS_OFS_Y", "COMPASS_OFS_Z", "COMPASS_DIA_X",
                                      "COMPASS_ODI_X"))
    for axis in "XYZ":
        assert learnt[f"COMPASS_OFS_{axis}"] == pytest.approx(ARDUPILOT_REAL[f"SIM_MAG1_OFS_{axis}"], abs=10.0), words
    assert learnt["COMPASS_DIA_X"] == pytest.approx(1.0) and learnt["COMPASS_ODI_X"] == pytest.approx(0.0)


def test_ardupilot_highres_imu_is_its_compass_field_untruncated_in_its_own_unit(rig_factory):
    """ArduPilot's HIGHRES_IMU magnetometer is ``compass.get_field() * 1000`` (1e-6 gauss, not the spec's
    gauss) and RAW_IMU the same field cut to whole milligauss toward zero. Read as ArduPilot's family,
    both give the same field within half a count (50 nT), and a plausible Earth field."""
    rig = rig_factory("highres")
    mon = rig.monitor
    for name in ("HIGHRES_IMU", "RAW_IMU"):
        mon.send_command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), 1e5)
    decoder = MavlinkDecoder(MessageClock(), mag_message=mag_messages("ardupilot"), imu=False,
                             highres_nt_per_unit=highres_nt_per_unit("ardupilot"))
    pairs, last_raw = [], None
    while len(pairs) < 20:   # the monitor's own pump does not keep these messages: read them here
        msg = mon.conn.recv_match(type=["HIGHRES_IMU", "RAW_IMU"], blocking=True, timeout=WALL_S)
        assert msg is not None, "no HIGHRES_IMU / RAW_IMU from ArduPilot"
        if msg.get_type() == "RAW_IMU":
            last_raw = msg if (msg.xmag, msg.ymag, msg.zmag) != (0, 0, 0) else None   # the compass is up
        elif last_raw is not None:
            pairs.append((last_raw, msg))
    for raw, high in pairs:
        assert (int(high.xmag / 1000.0), int(high.ymag / 1000.0), int(high.zmag / 1000.0)) == \
            (raw.xmag, raw.ymag, raw.zmag)
        [from_raw] = decoder.decode(raw) or [None]
        [from_high] = decoder.decode(high)
        if from_raw is not None:            # the first RAW_IMU only: HIGHRES_IMU takes over
            assert max(abs(a - b) for a, b in zip(from_raw.mag_body_nt, from_high.mag_body_nt)) <= 50.0
        assert 20_000.0 < math.hypot(*from_high.mag_body_nt) < 70_000.0
    assert decoder.superseded == {"RAW_IMU"}


def test_companion_sigkill_stops_the_vehicle_within_ardupilots_timeout(rig_factory):
    rig = rig_factory("sigkill")
    rig.start_companion(NAV_DEST_LAT=31.0, NAV_DEST_LON=154.0, NAV_PERIOD_S=60.0)
    mon = rig.monitor
    mon.pump(rig.said("phase probe1"), WALL_S, "first probing move")
    t_probe = mon.time_s
    mon.pump(lambda m: m.time_s >= t_probe + 30.0, WALL_S, "cruising")
    assert _moving(mon.truth, t_probe + 10.0, mon.time_s), "not moving before the kill"
    os.kill(rig.companion.pid, signal.SIGKILL)
    rig.companion.wait(timeout=10)
    t_kill = mon.time_s
    mon.pump(lambda m: bool(m.texts_matching("target not received", 1)) or m.time_s > t_kill + 10.0, WALL_S,
             "ArduPilot's setpoint timeout")
    [(t_stop, _, _)] = mon.texts_matching("target not received", 1)[-1:] or [(float("inf"), 0, "")]
    assert t_stop - t_kill <= 3.0 + 0.5, f"stopped {t_stop - t_kill:.1f} s after the kill"
    mon.pump(lambda m: m.time_s >= t_stop + 30.0, WALL_S, "coasting down")
    assert not _moving(mon.truth, t_stop + 20.0, t_stop + 30.0, min_speed_mps=1.0), "still moving 20 s after stopping"


def test_arming_refusal_reaches_the_operator_with_backoff(rig_factory):
    """GPS lost before arming: ArduPilot refuses (its GPS check); the operator hears why, from the
    companion, and the retries back off instead of hammering every 2 s."""
    rig = rig_factory("arming", params={"SIM_GPS1_ENABLE": 0})
    rig.start_companion(NAV_DEST_LAT=31.0, NAV_DEST_LON=154.0, NAV_PERIOD_S=30.0)
    mon = rig.monitor
    mon.pump(lambda m: len(m.texts_matching("arming refused", 191)) >= 3, WALL_S, "three arming refusals")
    refusals = mon.texts_matching("arming refused", 191)
    assert all("(" in text and "retry in" in text for _, _, text in refusals)
    waits = [float(text.rsplit("retry in", 1)[1].split()[0]) for _, _, text in refusals[:3]]
    assert waits == sorted(waits) and waits[-1] > waits[0], waits
    assert not mon.armed


def test_main_job_says_in_one_line_when_the_firmware_is_missing(tmp_path):
    import subprocess
    import sys

    env = {**os.environ, "FCMPC_ARDUPILOT": str(tmp_path / "no-such-ardurover")}
    done = subprocess.run([sys.executable, "-m", "fcmpc.fly.cli", "--fc", "ardupilot", "--out-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, env=env, timeout=120, stdin=subprocess.DEVNULL,
                          cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no-such-ardurover" in lines[0] and "Traceback" not in done.stderr
    assert not (tmp_path / "run").exists()                          # nothing written for a run that never started


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["sigterm", "sigint-in-background"])
def test_main_job_stopped_by_a_signal_still_writes_its_records(tmp_path, signum):
    """``fcmpc-fly --fc ardupilot`` stopped by SIGTERM (a supervisor, ``kill``, ``timeout``) writes the
    truth, the result and the summary as Ctrl-C does (the full Pacific run of 2026-12-01, stopped so,
    left only the companion's steps). SIGINT stops it too when it was started as a background job
    of a non-interactive shell, which starts it with SIGINT ignored (``kill -INT`` once did nothing)."""
    import json
    import subprocess
    import sys

    from fcmpc.firmware.instances import claimed_instance
    from tests.firmware.conftest import REPO, _binary_or_skip
    from tests.processes import Lines, reaped

    def as_background_job() -> None:       # what `cmd &` in a script does to SIGINT
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    _binary_or_skip()
    out = tmp_path / "run"
    with claimed_instance("ardupilot", 71, 99) as instance:       # held until the run has ended
        proc = subprocess.Popen([sys.executable, "-m", "fcmpc.fly.cli", "--fc", "ardupilot", "--fc-instance",
                                 str(instance), "--short", "--short-km", "20", "--no-tlog", "--no-plot",
                                 "--out-dir", str(out)], cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True,
                                preexec_fn=as_background_job if signum == signal.SIGINT else None)
        with reaped(proc):
            lines = Lines(proc.stderr)
            for _ in range(2):      # the second progress line (30 s of wall time apart): the flight is under way
                assert lines.wait_for(" h simulated, ", WALL_S) is not None, lines.seen
            proc.send_signal(signum)
            stdout, _ = proc.communicate(timeout=120)
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "interrupted" and signal.Signals(signum).name in result["message"], result
    assert stdout.startswith("fcmpc-fly: interrupted before arriving"), stdout
    assert len((out / "truth.csv").read_text().splitlines()) > 10     # the samples recorded until then

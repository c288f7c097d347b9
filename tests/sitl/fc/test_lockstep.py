"""sitl.fc.lockstep over real loopback sockets: time advances only with the companion, and a closed loop is bit-reproducible."""
from __future__ import annotations

import math
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.sitl.fc.helpers import ARM, DO_SET_MODE, GUIDED, HOLD, SET_INTERVAL, send_velocity, stop_and_wait


def test_lockstep_advances_only_with_the_companion(sitl):
    server, client = sitl(lockstep=True, lockstep_timeout_s=0.3, lockstep_start_timeout_s=10.0, init_s=0.2,
                          speedup=None, duration_s=None)
    # answer each boundary (SYSTEM_TIME at every 0.2 s) with a setpoint stamped with that time
    answered = 0
    last = -1
    while answered < 50:
        st = client.recv("SYSTEM_TIME", 5.0)
        if st.time_boot_ms > last:
            last = st.time_boot_ms
            client.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            answered += 1
    t_answered = client.time_ms()
    assert server.gate.timeouts == 0
    assert t_answered == pytest.approx(50 * 200, abs=600)
    # silence: one period per timeout (0.3 s wall), never a deadlock; waited for by the count, not a
    # fixed sleep (a loaded machine's second is not the simulator's): what is judged is the ratio
    deadline = time.monotonic() + 30.0
    while server.gate.timeouts < 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    timeouts = server.gate.timeouts
    advanced = server.t_us / 1000 - t_answered
    assert timeouts >= 2
    assert 0 < advanced <= (timeouts + 2) * 200   # to the next boundary, one more per timeout (and one read late)


def test_lockstep_timed_answers_are_exact(sitl):
    server, client = sitl(lockstep=True, lockstep_timeout_s=2.0, init_s=0.2, speedup=None, duration_s=None)
    for _ in range(30):
        st = client.recv("SYSTEM_TIME", 5.0)
        # a setpoint stamped with the boundary it answers (ignored in HOLD, but it answers the step)
        send_velocity(client, st.time_boot_ms, 0.0, 0.0)
    time.sleep(0.3)
    # the simulator can be at most one period ahead of the last answered boundary
    assert server.gate.timeouts == 0
    assert server.gate.peer_time_ms >= 0
    assert server.t_us / 1000 <= server.gate.peer_time_ms + 2 * 200


def _scripted_companion(client, boundaries: int) -> None:
    """A deterministic companion: arm and GUIDED once the vehicle is ready, then at every lockstep
    boundary a setpoint computed from the latest GLOBAL_POSITION_INT, stamped with the boundary."""
    latest = None
    commanded = False
    answered = 0
    while answered < boundaries:
        msg = client.recv(["SYSTEM_TIME", "GLOBAL_POSITION_INT", "HEARTBEAT"], 10.0)
        name = msg.get_type()
        if name == "GLOBAL_POSITION_INT":
            latest = msg
        elif name == "HEARTBEAT":
            if msg.get_srcComponent() == 1 and msg.custom_mode == HOLD and not commanded:
                client.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
                client.mav.command_long_send(1, 1, DO_SET_MODE, 0, 1, GUIDED, 0, 0, 0, 0, 0)
                commanded = True
        else:
            b = msg.time_boot_ms
            north = (32.99 - latest.lat / 1e7) if latest else 0.0
            east = (152.01 - latest.lon / 1e7) if latest else 0.0
            course = math.atan2(east * math.cos(math.radians(33.0)), north)
            speed = 6.0 + 2.0 * math.sin(b / 7000.0)
            send_velocity(client, b, speed * math.cos(course), speed * math.sin(course))
            answered += 1


@pytest.mark.parametrize("slack", [1, 0])
def test_lockstep_closed_loop_is_bit_reproducible(sitl, tmp_path, slack):
    logs = []
    for run in range(2):
        folder = tmp_path / f"run{run}"
        server, client = sitl(lockstep=True, lockstep_slack=slack, speedup=None, duration_s=60.0, init_s=0.2,
                              seed=11, log_dir=str(folder), tlog=str(folder / "sitl.tlog"))
        _scripted_companion(client, boundaries=301)           # 0.0, 0.2, ... 60.0
        stop_and_wait(server)
        assert server.gate.timeouts == 0 and server.summary["sim_s"] == pytest.approx(60.0)
        assert server.state.distance_m > 150.0
        logs.append((folder / "truth.csv").read_bytes())
    assert logs[0] == logs[1]


def test_a_lockstep_run_ending_off_a_boundary_sends_every_frame_it_logged(tmp_path):
    """Frames held after the last boundary (duration 1.3 s, period 0.2 s) still leave at the end of the run:
    what a reader receives on its socket is exactly the tlog, and as many frames as tx_messages."""
    import socket

    from sitl.fc.config import ServerConfig
    from sitl.fc.server import SitlServer
    from tests.sitl.conftest import read_tlog
    from tests.sitl.fc.test_outbox import frames_of

    reader = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    reader.bind(("127.0.0.1", 0))
    try:
        server = SitlServer(ServerConfig(outs=(f"udp:127.0.0.1:{reader.getsockname()[1]}",), lockstep=True,
                                         lockstep_period_s=0.2, lockstep_timeout_s=0.02,
                                         lockstep_start_timeout_s=0.02, duration_s=1.3, init_s=0.2, seed=3,
                                         quiet=True, log_dir=str(tmp_path / "run"), tlog=""))
        summary = server.run()                  # nobody answers: each boundary times out
        reader.setblocking(False)
        received = []
        while True:
            try:
                received += frames_of(reader.recv(65536))
            except BlockingIOError:
                break
    finally:
        reader.close()
    logged = [m.get_msgbuf() for m in read_tlog(tmp_path / "run" / "sitl.tlog")]
    assert summary["sim_s"] == pytest.approx(1.3) and summary["lockstep_timeouts"] >= 6
    assert len(logged) == summary["tx_messages"] > 0
    assert b"".join(received) == b"".join(logged), f"{len(received)} frames received, {len(logged)} logged"


def test_with_the_companions_pid_the_world_waits_while_it_lives_and_goes_on_once_it_has_ended(sitl):
    """``--lockstep-peer-pid``: no wall timeout (here 0.05 s, which would pass a boundary every 0.05 s of
    a silence) while the process runs, however long it is silent; once it has ended the world goes on
    at once, without counting a timeout."""
    import subprocess
    import sys

    peer = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        server, client = sitl(lockstep=True, lockstep_timeout_s=0.05, lockstep_peer_pid=peer.pid, init_s=0.2,
                              speedup=None, duration_s=None)
        for _ in range(5):
            st = client.recv("SYSTEM_TIME", 30.0)
            send_velocity(client, st.time_boot_ms, 0.0, 0.0)
        waited_ms = client.recv("SYSTEM_TIME", 30.0).time_boot_ms     # the boundary nobody answers
        silent_until = time.monotonic() + 1.0     # 20 of the wall timeouts that no longer apply
        while time.monotonic() < silent_until:
            assert server.t_us // 1000 <= waited_ms + 200, "the world went on without a live companion"
            time.sleep(0.05)
        assert server.gate.timeouts == 0 and server.stepper.peer_gone_s is None
        peer.stdin.close()      # it ends; not reaped yet (a zombie, as a test's companion is until waited for)
        deadline = time.monotonic() + 30.0        # a hang guard: the world goes on on the event
        while server.t_us // 1000 < waited_ms + 10 * 200:
            assert time.monotonic() < deadline, "the world still waits for an ended companion"
            time.sleep(0.02)
        assert server.gate.timeouts == 0 and server.stepper.peer_gone_s == pytest.approx(waited_ms / 1000, abs=0.2)
    finally:
        if peer.poll() is None:
            peer.kill()
        peer.wait(timeout=30)


def test_the_companions_start_up_burst_before_its_clock_is_one_answer(sitl):
    """Before its clock starts (no stamp yet) the companion answers the first boundaries with unstamped
    messages: its stream requests and parameter reads, sent in one datagram. The whole datagram is
    that answer. Each message of it used to count as the answer to a boundary of its own, so the
    companion's start-up requests (about 20) were read one 0.2 s boundary apart and its parameter reads
    4 s of simulated time late: it asked again, twice, and the flight controller answered each time."""
    server, client = sitl(lockstep=True, lockstep_timeout_s=60.0, lockstep_peer=(1, 191), init_s=0.2,
                          speedup=None, duration_s=None)
    last = client.time_ms()                           # the first boundary: the companion's clock starts here
    mav = client.mav
    burst = [mav.command_long_encode(1, 1, SET_INTERVAL, 0, msg_id, 100_000, 0, 0, 0, 0, 0)
             for msg_id in (24, 27, 30, 33, 74, 105, 116, 2, 1, 24, 27, 30, 33, 74)]
    burst.append(mav.param_request_read_encode(1, 1, b"EK3_SRC1_YAW", -1))
    client.conn.write(b"".join(msg.pack(mav) for msg in burst))          # one datagram, as the companion's pass
    answered_ms = None
    while answered_ms is None and last < 6000:
        msg = client.recv(["SYSTEM_TIME", "PARAM_VALUE"], 30.0)
        if msg.get_type() == "PARAM_VALUE":
            answered_ms = last
        elif msg.time_boot_ms > last:                 # a boundary: answered, still without a stamp
            last = msg.time_boot_ms
            mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert answered_ms is not None and answered_ms <= 400, f"read answered at {answered_ms} ms of simulated time"
    assert server.gate.timeouts == 0


@pytest.mark.parametrize("fault", ["link_delay:1:2:1.0", "link_loss:1:1:1.0"], ids=["delay_ends", "link_cut"])
def test_with_the_companions_pid_a_link_fault_never_leaves_the_world_waiting_for_an_answer_it_cannot_get(
        sitl, fault):
    """In lockstep on a live companion's PID (no wall timeout) the world waits only for answers to
    what reached the companion. The boundary it waited for used to be the one it sent, less the
    delay in force: when a 1 s link_delay ended the FIFO still held the last second, so the
    companion could answer 1 s less than asked and the world waited for ever (the fault matrix's
    hang with 39aaf3c); a cut link (link_loss 1.0) delivers nothing to answer at all."""
    import os

    from tests.sitl.fc.helpers import Answering

    server, client = sitl(lockstep=True, lockstep_peer_pid=os.getpid(), lockstep_hang_s=60.0, init_s=0.2,
                          speedup=None, duration_s=None, faults=(fault,))
    companion = Answering(client, hang_s=30.0)     # answers every SYSTEM_TIME it receives, as the companion
    assert companion.until(5000) == []             # past the fault's end: reached, not a TimeoutError
    assert server.gate.timeouts == 0 and server.stepper.hangs == 0
    assert server.counters.get("tx_delayed_fault" if "delay" in fault else "tx_dropped_fault", 0) > 0


def test_a_live_companion_that_never_answers_stops_the_run_as_a_hang(tmp_path):
    """The hang guard (``--lockstep-hang-s``): a companion process that lives but answers nothing ends
    the stand-in with exit code 4 and ``lockstep_hangs`` 1, instead of a world going on alone."""
    import json
    import subprocess
    import sys

    from tests.sitl.conftest import REPO

    peer = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "sitl.fc", "--lockstep", "--lockstep-peer-pid", str(peer.pid),
             "--lockstep-hang-s", "1", "--duration", "60", "--out", "udp:127.0.0.1:9", "--quiet",
             "--log-dir", str(tmp_path / "run")],
            check=False, cwd=REPO, capture_output=True, timeout=120)
    finally:
        peer.stdin.close()
        peer.wait(30)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert proc.returncode == 4, proc.stderr.decode(errors="replace")[-2000:]
    assert summary["lockstep_hangs"] == 1 and summary["sim_s"] < 1.0
    assert b"answered nothing for 1 s" in proc.stderr

"""MAVLink 2 signing of the companion's link: key file, persisted timestamp, refusals over real
sockets against pymavlink peers configured as MAVProxy configures itself (issue 10, item 1)."""
from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.io.link import MavlinkLink, mavlink
from companion.io.link.signing import (
    SIGNED_ONLY_IDS,
    Signing,
    SigningError,
    TimestampStore,
    passphrase_key,
    read_key_file,
    signing_timestamp,
    write_key_file,
)
from companion.io.param_server import ParamServer
from tests.ports import free_port

REPO = Path(__file__).resolve().parents[2]
KEY = passphrase_key("correct horse battery staple")
OTHER_KEY = passphrase_key("not the key")


def test_key_file_is_private_and_its_content_never_in_an_error(tmp_path):
    path = write_key_file(tmp_path / "k", KEY)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and read_key_file(path) == KEY
    with pytest.raises(SigningError, match="exists"):
        write_key_file(path, KEY)
    path.chmod(0o644)
    with pytest.raises(SigningError, match="permission 0644") as err:
        read_key_file(path)
    assert KEY.hex() not in str(err.value)
    path.chmod(0o600)
    path.write_text("00" * 31 + "\n")
    with pytest.raises(SigningError, match="64 hex") as err:
        read_key_file(path)
    assert "00" * 31 not in str(err.value)


def test_signed_only_set_covers_parameter_writes_commands_and_set_messages():
    names = {mavlink.mavlink_map[i].msgname for i in SIGNED_ONLY_IDS}
    assert {"PARAM_SET", "COMMAND_LONG", "COMMAND_INT", "SET_POSITION_TARGET_GLOBAL_INT", "SET_MODE",
            "SETUP_SIGNING"} <= names
    assert not names & {"HEARTBEAT", "ATTITUDE", "SYSTEM_TIME", "PARAM_VALUE", "RAW_IMU"}


def test_timestamp_never_goes_back_across_restarts_even_with_the_clock_behind(tmp_path):
    store_path = tmp_path / "k.timestamp"
    now = 1_800_000_000.0
    first = TimestampStore(store_path)
    t0 = first.start(now)
    used = t0 + 5_000_000          # 50 s of signing on the first run
    first.ensure(used)
    # restart with the board's clock a day behind (no RTC battery): still above everything signed
    again = TimestampStore(store_path).start(now - 86400.0)
    assert again > used
    assert t0 >= signing_timestamp(now)


class Rig:
    """A signing link serving parameters; a GCS (255) with the key, and a stranger's pymavlink."""

    def __init__(self, tmp_path: Path) -> None:
        self.port = free_port()
        key_file = write_key_file(tmp_path / "signing.key", KEY)
        self.link = MavlinkLink(f"udpin:127.0.0.1:{self.port}", signing=Signing.from_file(key_file, link_id=7))
        self.link.open()
        self.server = ParamServer(self.link, tmp_path / "c.parm")
        self.server.load()

    def peer(self, sysid: int, key: bytes | None, allow_unsigned: bool = False):
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.port}", source_system=sysid, source_component=190)
        if key is not None:   # as MAVProxy's signing module does: sign, accept unsigned only RADIO*
            conn.setup_signing(key, sign_outgoing=True,
                               allow_unsigned_callback=(lambda mav, msg_id: allow_unsigned), link_id=1)
        return conn

    def pump(self, until, timeout_s: float = 5.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not until():
            if self.link.wait_readable(0.05):
                for msg in self.link.read():
                    self.server.mavlink_packet(msg)

    def close(self) -> None:
        self.link.close()


def test_unsigned_and_badly_signed_writes_refused_signed_accepted(tmp_path):
    rig = Rig(tmp_path)
    gcs, unsigned, wrong = rig.peer(255, KEY), rig.peer(255, None), rig.peer(255, OTHER_KEY)
    try:
        unsigned.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 30.0, mavlink.MAV_PARAM_TYPE_REAL32)
        unsigned.mav.command_long_send(1, 191, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
        unsigned.mav.heartbeat_send(6, 8, 0, 0, 4)     # telemetry may come unsigned
        wrong.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 31.0, mavlink.MAV_PARAM_TYPE_REAL32)
        signing = rig.link.signing
        rig.pump(lambda: sum(signing.refused.values()) >= 2 and signing.bad_signatures >= 1
                 and signing.unsigned_accepted >= 1)
        assert signing.refused == {"PARAM_SET": 1, "COMMAND_LONG": 1}
        assert signing.bad_signatures == 1 and signing.unsigned_accepted == 1
        assert rig.server.values["NAV_SPEED_KMH"] == 50.0
        gcs.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 32.0, mavlink.MAV_PARAM_TYPE_REAL32)
        rig.pump(lambda: rig.server.values["NAV_SPEED_KMH"] == 32.0)
        assert rig.server.values["NAV_SPEED_KMH"] == 32.0
        # the reply is signed: a peer that refuses unsigned frames (MAVProxy's default) reads it
        reply = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=3.0)
        assert reply is not None and reply.param_value == 32.0 and gcs.mav.signing.goodsig_count >= 1
    finally:
        for conn in (gcs, unsigned, wrong):
            conn.close()
        rig.close()


def test_a_replayed_signed_frame_is_refused(tmp_path):
    rig = Rig(tmp_path)
    gcs = rig.peer(255, KEY)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        msg = mavlink.MAVLink_param_set_message(1, 191, b"NAV_SPEED_KMH", 33.0, mavlink.MAV_PARAM_TYPE_REAL32)
        frame = msg.pack(gcs.mav)
        raw.sendto(frame, ("127.0.0.1", rig.port))
        rig.pump(lambda: rig.server.values["NAV_SPEED_KMH"] == 33.0)
        rig.server.set_value("NAV_SPEED_KMH", 50.0)
        raw.sendto(frame, ("127.0.0.1", rig.port))   # the same signed bytes again, from another port
        rig.pump(lambda: rig.link.signing.bad_signatures >= 1)
        assert rig.server.values["NAV_SPEED_KMH"] == 50.0 and rig.link.signing.bad_signatures == 1
    finally:
        raw.close()
        gcs.close()
        rig.close()


def test_keygen_command_writes_a_private_key_and_prints_the_mavproxy_line(tmp_path):
    path = tmp_path / "keys" / "signing.key"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-m", "companion.io.link.keygen", str(path)], capture_output=True,
                         text=True, env=env, timeout=120, check=True).stdout
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    passphrase = next(line.split()[-1] for line in out.splitlines() if "signing setup" in line)
    assert passphrase_key(passphrase) == read_key_file(path)           # what MAVProxy derives
    assert read_key_file(path).hex() in out                              # SETUP_SIGNING's secret_key
    again = subprocess.run([sys.executable, "-m", "companion.io.link.keygen", str(path)], capture_output=True,
                           text=True, env=env, timeout=120)
    assert again.returncode == 2 and "exists" in again.stderr and read_key_file(path).hex() not in again.stderr


def test_companion_refuses_a_key_others_can_read_in_one_line(tmp_path):
    key_file = write_key_file(tmp_path / "signing.key", KEY)
    key_file.chmod(0o640)
    result = subprocess.run([sys.executable, "-m", "companion.app", "--signing-key", str(key_file), "--log-dir",
                             str(tmp_path / "log"), "--quiet"], capture_output=True, text=True, timeout=120,
                            env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert result.returncode == 2 and "permission 0640" in result.stderr and len(result.stderr.splitlines()) == 1
    assert KEY.hex() not in result.stderr

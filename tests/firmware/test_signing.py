"""MAVLink 2 signing against ArduPilot's own firmware (ardurover SITL): once the autopilot holds the
key (SETUP_SIGNING over SERIAL0, which ArduPilot treats as its secure USB channel), an unsigned
companion on SERIAL1 is not heard at all (ArduPilot accepts unsigned only RADIO_STATUS/RADIO there)
and a companion with the key is: its signed STATUSTEXTs are routed to the ground station and it
parses the autopilot's signed telemetry (it detects the flight controller and starts up)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

from companion.io.link.signing import passphrase_key, signing_timestamp, write_key_file
from companion.params import write_parm_file
from fcmpc.firmware.processes import stop_process
from tests.firmware.conftest import REPO

PASSPHRASE = "fcmpc firmware signing test"


def _companion(rig, name: str, key_file=None) -> subprocess.Popen:
    parm = rig.tmp / f"{name}.parm"
    write_parm_file(parm, {"NAV_START_LAT": 33.0, "NAV_START_LON": 152.0})
    argv = [sys.executable, "-m", "companion.app", "--connect", rig.sitl.serial1, "--params", str(parm),
            "--log-dir", str(rig.tmp / name), "--quiet"]
    if key_file is not None:
        argv += ["--signing-key", str(key_file)]
    return subprocess.Popen(argv, cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=open(rig.tmp / f"{name}.err", "wb"), env=dict(os.environ, PYTHONPATH=str(REPO)))


def test_signing_ardupilot_hears_only_the_signed_companion(rig_factory):
    rig = rig_factory("signing")
    mon = rig.monitor
    key = passphrase_key(PASSPHRASE)
    mon.conn.mav.setup_signing_send(1, 1, list(key), signing_timestamp(time.time()))
    mon.pump(lambda m: m.time_s > 5.0, 120.0, "firmware running")
    # the control: an unsigned companion on SERIAL1 -- ArduPilot drops every frame it sends
    unsigned = _companion(rig, "unsigned")
    try:
        start = mon.time_s
        mon.pump(lambda m: m.time_s > start + 40.0, 300.0, "40 s of firmware time")
        assert not mon.texts_matching("FcMPC", component=191)
    finally:
        stop_process(unsigned)
    key_file = write_key_file(rig.tmp / "signing.key", key)
    signed = _companion(rig, "signed", key_file)
    try:
        mon.pump(lambda m: bool(m.texts_matching("detected", component=191)), 300.0, "the signed companion heard")
        mon.pump(lambda m: bool(m.texts_matching("ready", component=191)), 300.0, "start-up on signed streams")
        assert signed.poll() is None
    finally:
        stop_process(signed)
    err = (rig.tmp / "signed.err").read_text(errors="replace")
    assert key.hex() not in err and PASSPHRASE not in err
    assert not any(key.hex() in p.read_text(errors="replace") for p in (rig.tmp / "signed").glob("*.json"))

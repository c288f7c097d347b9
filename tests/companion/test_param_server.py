"""The parameter server over a real UDP socket with a pymavlink client, and atomic persistence."""
from __future__ import annotations

import math
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.io.link import MavlinkLink, mavlink  # noqa: E402
from companion.io.param_server import ParamServer, decode_value, encode_value  # noqa: E402
from companion.params import REGISTRY, SPEC_BY_NAME, default_values, read_parm_file, write_parm_file  # noqa: E402
from tests.ports import free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


class Served:
    """A ParamServer on its own MavlinkLink, pumped by a thread; a GCS-like pymavlink client."""

    def __init__(self, parm: Path, encoding: str = "auto", clock=None) -> None:
        port = free_port()
        self.link = MavlinkLink(f"udpin:127.0.0.1:{port}")
        self.link.open()
        self.changes: list[tuple[str, float]] = []
        self.server = ParamServer(self.link, parm, on_change=lambda n, v: self.changes.append((n, v)),
                                  encoding=encoding, clock=clock)
        self.server.load()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()
        self.client = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                                 source_component=190)

    def _pump(self) -> None:
        while not self._stop.is_set():
            if self.link.wait_readable(0.05):
                for msg in self.link.read():
                    self.server.mavlink_packet(msg)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.link.close()
        self.client.close()

    def recv(self, mtype: str, timeout: float = 3.0, condition=None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.client.recv_match(type=mtype, blocking=True, timeout=0.1)
            if msg is not None and (condition is None or condition(msg)):
                return msg
        return None

    def drain(self, timeout: float = 0.3) -> list:
        out, deadline = [], time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.client.recv_match(blocking=True, timeout=0.05)
            if msg is not None:
                out.append(msg)
        return out


@pytest.fixture
def served(tmp_path):
    s = Served(tmp_path / "companion.parm")
    yield s
    s.close()


def test_a_live_reading_is_as_old_as_its_last_set_and_one_from_the_file_is_none(tmp_path):
    """NAV_SYMH from the .parm file has no age (inf: not a live reading); each set over the link,
    a repeated value too, makes it as old as the message time since. A reading is never written to
    the file (it would never count from there), neither alone nor beside a setting; a setting is,
    at once."""
    parm = tmp_path / "companion.parm"
    write_parm_file(parm, {**default_values(), "NAV_SYMH": -300.0})
    now = [100.0]
    served = Served(parm, clock=lambda: now[0])
    try:
        assert served.server.values["NAV_SYMH"] == -300.0 and served.server.age_s("NAV_SYMH", 100.0) == math.inf
        writes, on_disk = served.server.writes, parm.read_bytes()
        for at in (100.0, 160.0):   # the same value twice, a minute apart
            now[0] = at
            served.client.mav.param_set_send(1, 191, b"NAV_SYMH", -42.0, mavlink.MAV_PARAM_TYPE_REAL32)
            assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_SYMH") is not None
            assert served.server.values["NAV_SYMH"] == -42.0
            assert served.server.age_s("NAV_SYMH", at + 50.0) == pytest.approx(50.0)
        assert served.server.writes == writes and parm.read_bytes() == on_disk   # a reading: never written
        assert served.server.age_s("NAV_KP", 200.0) == math.inf
        served.client.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 40.0, mavlink.MAV_PARAM_TYPE_REAL32)
        assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_SPEED_KMH") is not None
        assert served.server.writes == writes + 1 and read_parm_file(parm)["NAV_SPEED_KMH"] == 40.0
        # ... with the settings alone: the readings (the file's old NAV_SYMH too) are not written beside it
        assert not {"NAV_SYMH", "NAV_KP"} & set(read_parm_file(parm))
    finally:
        served.close()


def test_list_all_parameters(served):
    served.client.mav.param_request_list_send(1, 191)
    got = {}
    deadline = time.monotonic() + 5.0
    while len(got) < len(REGISTRY) and time.monotonic() < deadline:
        msg = served.recv("PARAM_VALUE", 1.0)
        if msg is not None:
            got[msg.param_id] = msg
    assert set(got) == {spec.name for spec in REGISTRY}
    for index, spec in enumerate(REGISTRY):
        msg = got[spec.name]
        assert msg.param_index == index and msg.param_count == len(REGISTRY)
        assert msg.get_srcComponent() == 191
        expected_type = mavlink.MAV_PARAM_TYPE_INT32 if spec.kind is int else mavlink.MAV_PARAM_TYPE_REAL32
        assert msg.param_type == expected_type
        assert msg.param_value == pytest.approx(spec.default, rel=1e-6)      # C cast before any FC is heard


def test_read_one_by_name_and_by_index(served):
    served.client.mav.param_request_read_send(1, 191, b"NAV_SPEED_KMH", -1)
    msg = served.recv("PARAM_VALUE")
    assert msg.param_id == "NAV_SPEED_KMH" and msg.param_value == pytest.approx(50.0)
    index = [s.name for s in REGISTRY].index("MPC_HORIZON")
    served.client.mav.param_request_read_send(1, 191, b"", index)
    msg = served.recv("PARAM_VALUE")
    assert msg.param_id == "MPC_HORIZON" and msg.param_value == 2.0 and msg.param_index == index


def test_set_in_range_is_applied_persisted_and_reported(served, tmp_path):
    served.client.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 42.5, mavlink.MAV_PARAM_TYPE_REAL32)
    msg = served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_SPEED_KMH")
    assert msg.param_value == pytest.approx(42.5)
    assert read_parm_file(tmp_path / "companion.parm")["NAV_SPEED_KMH"] == pytest.approx(42.5)
    assert served.changes == [("NAV_SPEED_KMH", 42.5)]
    # an integer, sent C-cast (MAVProxy) and bytewise (MAVSDK for a non-ArduPilot system): both understood
    served.client.mav.param_set_send(1, 191, b"NAV_MAX_STEPS", 321.0, mavlink.MAV_PARAM_TYPE_INT32)
    assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_MAX_STEPS").param_value == 321.0
    bits = struct.unpack("<f", struct.pack("<i", 654))[0]
    served.client.mav.param_set_send(1, 191, b"NAV_MAX_STEPS", bits, mavlink.MAV_PARAM_TYPE_INT32)
    assert served.recv("PARAM_VALUE", condition=lambda m: m.param_value == 654.0) is not None
    saved = read_parm_file(tmp_path / "companion.parm")
    assert saved["NAV_MAX_STEPS"] == 654 and isinstance(saved["NAV_MAX_STEPS"], int)


def test_set_out_of_range_is_refused_with_the_unchanged_value(served, tmp_path):
    served.client.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 1000.0, mavlink.MAV_PARAM_TYPE_REAL32)
    msgs = served.drain(1.0)
    values = [m for m in msgs if m.get_type() == "PARAM_VALUE"]
    texts = ["".join(m.text for m in msgs if m.get_type() == "STATUSTEXT")]   # chunks of a long text, joined
    assert values and values[-1].param_id == "NAV_SPEED_KMH" and values[-1].param_value == pytest.approx(50.0)
    assert any("NAV_SPEED_KMH" in t and "range" in t for t in texts), texts
    assert not (tmp_path / "companion.parm").exists()                  # nothing was written
    assert served.changes == [] and served.server.values["NAV_SPEED_KMH"] == 50.0
    served.client.mav.param_set_send(1, 191, b"MPC_HORIZON", 2.5, mavlink.MAV_PARAM_TYPE_INT32)   # not an integer
    assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "MPC_HORIZON").param_value == 2.0
    served.client.mav.param_set_send(1, 191, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert served.recv("STATUSTEXT", condition=lambda m: "NO_SUCH_PARAM" in m.text) is not None


def test_float32_rounding_of_a_bound_is_the_bound(served):
    # 0.1 as float32 is 0.10000000149: still the minimum of COMP_MAG_TMO_S, not below/above it
    served.client.mav.param_set_send(1, 191, b"COMP_MAG_TMO_S", 0.1, mavlink.MAV_PARAM_TYPE_REAL32)
    assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "COMP_MAG_TMO_S").param_value == \
        pytest.approx(0.1)
    assert served.server.values["COMP_MAG_TMO_S"] == 0.1


@pytest.mark.parametrize("target,answered", [((1, 191), True), ((1, 0), True), ((0, 0), True), ((0, 191), True),
                                             ((1, 1), False), ((1, 190), False), ((2, 191), False)])
def test_addressing(served, target, answered):
    served.client.mav.param_request_read_send(target[0], target[1], b"MPC_HORIZON", -1)
    got = served.recv("PARAM_VALUE", timeout=1.0 if answered else 0.5)
    assert (got is not None) == answered


def test_px4_style_bytewise_values(tmp_path):
    s = Served(tmp_path / "p.parm", encoding="bytewise")
    try:
        s.client.mav.param_request_read_send(1, 191, b"NAV_MAX_STEPS", -1)
        msg = s.recv("PARAM_VALUE")
        assert struct.unpack("<i", struct.pack("<f", msg.param_value))[0] == 1000
        assert msg.param_type == mavlink.MAV_PARAM_TYPE_INT32
    finally:
        s.close()


def test_encode_decode_round_trip():
    for spec in REGISTRY:
        for value in {spec.minimum, spec.default, spec.maximum}:
            for bytewise in (False, True):
                wire = struct.unpack("<f", struct.pack("<f", encode_value(spec, spec.kind(value), bytewise)))[0]
                assert decode_value(spec, wire) == pytest.approx(float(spec.kind(value)), rel=1e-6), spec.name


def test_broken_file_serves_defaults_and_is_not_overwritten(tmp_path):
    parm = tmp_path / "broken.parm"
    parm.write_text("NAV_SPEED_KMH 50\nMPC_HORIZON 99\n", encoding="utf-8")   # 99 is out of range
    link = MavlinkLink("udpout:127.0.0.1:9")
    link.open()
    try:
        server = ParamServer(link, parm)
        assert not server.load()
        assert "MPC_HORIZON" in server.load_error and "broken.parm:2" in server.load_error
        assert server.values == default_values()
        server.set_value("NAV_SPEED_KMH", 40.0)                      # lives in memory only
        assert server.values["NAV_SPEED_KMH"] == 40.0
        assert parm.read_text(encoding="utf-8") == "NAV_SPEED_KMH 50\nMPC_HORIZON 99\n"
    finally:
        link.close()


def test_good_file_is_loaded(tmp_path):
    parm = tmp_path / "good.parm"
    write_parm_file(parm, {"NAV_SPEED_KMH": 30.0, "COMP_ARM_ENABLE": 1})
    link = MavlinkLink("udpout:127.0.0.1:9")
    link.open()
    try:
        server = ParamServer(link, parm)
        assert server.load() and server.load_error is None
        assert server.values["NAV_SPEED_KMH"] == 30.0 and server.values["COMP_ARM_ENABLE"] == 1
    finally:
        link.close()


_WRITER = """
import sys
from companion.params import write_parm_file
a = {"NAV_SPEED_KMH": 11.0, "MPC_HORIZON": 3}
b = {"NAV_SPEED_KMH": 22.0, "MPC_HORIZON": 7, "NAV_MAX_STEPS": 77}
path = sys.argv[1]
write_parm_file(path, a)
print("ready", flush=True)
k = 0
while True:
    write_parm_file(path, b if k % 2 else a, header="x" * (k % 50))
    k += 1
"""


def test_persistence_is_atomic_under_sigkill(tmp_path):
    """A writer killed at random moments leaves either the old or the new file, never half of one."""
    parm = tmp_path / "atomic.parm"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    seen = set()
    for trial in range(8):
        proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(parm)], env=env, stdout=subprocess.PIPE)
        try:
            assert proc.stdout.readline().strip() == b"ready"
            time.sleep(0.05 + 0.037 * trial)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
        values = read_parm_file(parm)                                   # parses: never half-written
        assert values in ({"NAV_SPEED_KMH": 11.0, "MPC_HORIZON": 3},
                          {"NAV_SPEED_KMH": 22.0, "MPC_HORIZON": 7, "NAV_MAX_STEPS": 77})
        seen.add(len(values))
    leftovers = [p for p in tmp_path.iterdir() if p.name != "atomic.parm"]
    assert all(p.name.startswith(".atomic.parm.") for p in leftovers)  # only temporaries, never the target
    assert math.isfinite(len(seen))


def test_a_set_to_all_components_for_another_components_parameter_is_left_alone(served):
    """PARAM_SET CRUISE_SPEED to component 0 is the flight controller's business: no warning, no
    change; the same name addressed to us is refused with a STATUSTEXT."""
    served.client.mav.param_set_send(1, 0, b"CRUISE_SPEED", 14.0, mavlink.MAV_PARAM_TYPE_REAL32)
    served.client.mav.param_request_read_send(1, 191, b"MPC_HORIZON", -1)   # an event that the set was handled
    assert served.recv("PARAM_VALUE") is not None
    assert not [m for m in served.drain() if m.get_type() == "STATUSTEXT"]
    served.client.mav.param_set_send(1, 191, b"CRUISE_SPEED", 14.0, mavlink.MAV_PARAM_TYPE_REAL32)
    text = served.recv("STATUSTEXT")
    assert text is not None and "no parameter CRUISE_SPEED" in text.text
    assert served.server.sets_accepted == 0


# ---------------------------------------------------------------------- issue 10: who may write, and what
def _stranger(served, sysid: int = 200):
    return mavutil.mavlink_connection(f"udpout:127.0.0.1:{served.link.conn.remote[1]}", source_system=sysid,
                                      source_component=190)


def test_a_stranger_can_neither_write_nor_read(served, tmp_path):
    stranger = _stranger(served)
    try:
        stranger.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 40.0, mavlink.MAV_PARAM_TYPE_REAL32)
        stranger.mav.param_request_list_send(1, 191)
        deadline = time.monotonic() + 5.0
        while served.server.sets_from_strangers < 1 and time.monotonic() < deadline:
            time.sleep(0.02)   # the pump thread handles it; this only polls its counter
        assert served.server.sets_from_strangers == 1
        assert served.server.values["NAV_SPEED_KMH"] == 50.0 and not (tmp_path / "companion.parm").exists()
        assert stranger.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5) is None
    finally:
        stranger.close()


@pytest.mark.parametrize("name,value,why", [
    ("NAV_SPEED_KMH", 100.0, "> SAFE_SPEED_KMH 60"),           # in range (300), above the ceiling
    ("COMP_HB_TMO_S", 60.0, "> SAFE_TMO_S 5"),
    ("SAFE_SPEED_KMH", 300.0, "start-up only"),
    ("LINK_GCS_ID2", 200.0, "start-up only"),
    ("NAV_DEST_LAT", 10.0, "outside SAFE_FENCE_KM 100"),            # 2000 km off the route
])
def test_the_link_cannot_raise_the_safety_ceiling(served, tmp_path, name, value, why):
    before = served.server.values[name]
    kind = mavlink.MAV_PARAM_TYPE_INT32 if isinstance(before, int) else mavlink.MAV_PARAM_TYPE_REAL32
    served.client.mav.param_set_send(1, 191, name.encode(), value, kind)
    reply = served.recv("PARAM_VALUE", condition=lambda m: m.param_id == name)
    text = served.recv("STATUSTEXT", condition=lambda m: name in m.text)
    assert reply is not None and reply.param_value == before and served.server.values[name] == before
    assert text is not None and why in text.text
    assert not (tmp_path / "companion.parm").exists()


@pytest.mark.parametrize("first,name,value,why", [
    (("NAV_YEAR", 2026.5), "NAV_WMM", 1, "WMM2020 covers 2019.94..2025.00"),   # both in range, no model for both
    (None, "NAV_PROBE2_DEG", 180.0, "within 11.5 deg of parallel"),           # NAV_PROBE1_DEG 0: one line
])
def test_a_value_no_mission_can_fly_with_the_others_is_refused(served, tmp_path, first, name, value, why):
    """Each value in range, together no mission: the companion built its mission from them and
    raised (NAV_WMM 1 with NAV_YEAR 2026.5), or failed the probing. The write is refused, with the
    unchanged value and a STATUSTEXT saying why; the value set before it stays."""
    if first is not None:
        served.client.mav.param_set_send(1, 191, first[0].encode(), first[1], mavlink.MAV_PARAM_TYPE_REAL32)
        assert served.recv("PARAM_VALUE", condition=lambda m: m.param_id == first[0]).param_value == \
            pytest.approx(first[1])
    before = served.server.values[name]
    kind = mavlink.MAV_PARAM_TYPE_INT32 if isinstance(before, int) else mavlink.MAV_PARAM_TYPE_REAL32
    served.client.mav.param_set_send(1, 191, name.encode(), value, kind)
    msgs = served.drain(1.0)
    replies = [m for m in msgs if m.get_type() == "PARAM_VALUE" and m.param_id == name]
    text = "".join(m.text for m in msgs if m.get_type() == "STATUSTEXT")   # chunks of a long text, joined
    assert replies and replies[-1].param_value == before and served.server.values[name] == before
    assert f"{name}=" in text and why in text, text


def test_a_destination_near_the_route_is_accepted(served):
    served.client.mav.param_set_send(1, 191, b"NAV_DEST_LAT", 28.3, mavlink.MAV_PARAM_TYPE_REAL32)   # 33 km north
    reply = served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_DEST_LAT")
    assert reply is not None and reply.param_value == pytest.approx(28.3)


def test_a_write_to_every_system_is_refused(served):
    served.client.mav.param_set_send(0, 191, b"NAV_MAX_STEPS", 500.0, mavlink.MAV_PARAM_TYPE_INT32)
    served.client.mav.param_request_read_send(1, 191, b"NAV_MAX_STEPS", -1)
    reply = served.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_MAX_STEPS")
    assert reply is not None and reply.param_value == 1000.0


def test_unchanged_value_not_rewritten_and_stale_temporaries_removed(tmp_path):
    parm = tmp_path / "companion.parm"
    stale = tmp_path / ".companion.parm.abc123.tmp"      # what a kill during write_parm_file leaves
    stale.write_text("NAV_SPEED_KMH 1\n")
    s = Served(parm)
    try:
        assert not stale.exists() and s.server.stale_removed == 1
        s.client.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 42.0, mavlink.MAV_PARAM_TYPE_REAL32)
        assert s.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_SPEED_KMH") is not None
        written = parm.stat().st_mtime_ns
        for _ in range(3):
            s.client.mav.param_set_send(1, 191, b"NAV_SPEED_KMH", 42.0, mavlink.MAV_PARAM_TYPE_REAL32)
            assert s.recv("PARAM_VALUE", condition=lambda m: m.param_id == "NAV_SPEED_KMH") is not None
        assert s.server.writes == 1 and parm.stat().st_mtime_ns == written and s.server.sets_accepted == 4
        assert s.changes == [("NAV_SPEED_KMH", 42.0)]
    finally:
        s.close()

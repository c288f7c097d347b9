"""The status page (``fcmpc-companion --http``) of a real companion flying against the stand-in.

One module fixture: the companion with ``--http`` on a free loopback port and the stand-in in
lockstep for FLOWN_S simulated seconds (probe steps and cruise steps at NAV_PERIOD_S 60). The
stand-in then exits; the companion keeps running and serving (its state then stands still: the
mission's message time stops with the stand-in), and the tests read the page, the JSON state, a
headless Chromium screenshot, and throw bad requests at it.
"""
from __future__ import annotations

import http.client
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from companion.io.records import STEP_COLUMNS, StepRecorder, read_steps_csv
from companion.io.status_page.plot import DEST_COLOUR, ELLIPSE_COLOUR, TRACK_COLOUR, ellipse_95
from companion.io.status_page.address import parse_http_address
from companion.io.status_page.server import MAX_CONNECTIONS, TrackReader
from companion.params import default_values
from fcmpc.firmware.processes import stop_process as _stop
from tests.lockstep import HANG_S, stand_in_lockstep_args
from tests.ports import free_port
from tests.processes import wait_for_file

REPO = Path(__file__).resolve().parents[2]
FLOWN_S = 300.0
SECRET = "outside-the-records-folder-4f1c"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Vehicle:
    def __init__(self, base: Path, port: int, companion: subprocess.Popen) -> None:
        self.base, self.port, self.companion = base, port, companion
        self.records = base / "companion"
        self.before_fc: dict = {}       # /state.json before the stand-in started

    def get(self, path: str, method: str = "GET", body: bytes | None = None,
            headers: dict | None = None) -> tuple[int, dict, bytes]:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=20)
        try:
            conn.request(method, path, body=body, headers=headers or {})
            resp = conn.getresponse()
            return resp.status, dict(resp.getheaders()), resp.read()
        finally:
            conn.close()

    def state(self) -> dict:
        status, _, body = self.get("/state.json")
        assert status == 200
        return json.loads(body)


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    base = tmp_path_factory.mktemp("status")
    udp, port = free_port(), free_port()
    parm = base / "companion.parm"
    parm.write_text("COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\n", encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1")
    companion = subprocess.Popen(
        [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{udp}", "--params", str(parm),
         "--log-dir", str(base / "companion"), "--lockstep", "--max-wall-s", "600", "--quiet", "--http", str(port)],
        env=env, stdout=subprocess.DEVNULL, stderr=open(base / "companion.err", "wb"))
    try:
        wait_for_file(base / "companion" / "steps.csv", [companion], HANG_S)   # the page is served from here on
        vehicle = Vehicle(base, port, companion)
        vehicle.before_fc = vehicle.state()
        sitl = subprocess.run(   # the world waits for the companion as long as it lives (tests/lockstep.py)
            [sys.executable, "-m", "sitl.fc", "--out", f"udp:127.0.0.1:{udp}", *stand_in_lockstep_args(companion.pid),
             "--duration", str(FLOWN_S), "--log-dir", str(base / "sitl"), "--quiet"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=HANG_S)
        assert sitl.returncode == 0
        # settled: the companion has entered its heartbeat failsafe (COMP_HB_TMO_S of wall time after
        # the stand-in's last heartbeat; its failsafe row is then in steps.csv), so nothing it holds
        # changes from here on; its message time by then is the stand-in's last
        deadline = time.monotonic() + HANG_S
        while not ((state := vehicle.state())["failsafe"] and state["msg_time_s"] >= FLOWN_S - 1.0):
            assert time.monotonic() < deadline and companion.poll() is None, state
            time.sleep(0.05)   # the polling interval, not a guess at a duration
        yield vehicle
    finally:
        _stop(companion)


def test_page_and_state_show_the_phase_and_the_estimate_of_the_records(vehicle):
    early = vehicle.before_fc
    assert early["state"] == "wait_fc" and early["phase"] == "" and early["est_lat_deg"] is None
    assert early["dest_lat_deg"] == default_values()["NAV_DEST_LAT"] and early["fc_mode"] == "unknown"
    state = vehicle.state()
    steps = [r for r in read_steps_csv(vehicle.records / "steps.csv") if r["event"] == "step"]
    last = steps[-1]
    assert state["state"] == "running" and state["phase"] == last["phase"] == "cruise"
    assert state["step"] == last["step"] >= 2 and state["mission"] == 1
    assert math.isfinite(state["est_lat_deg"]) and math.isfinite(state["est_lon_deg"])
    assert state["est_lat_deg"] == pytest.approx(last["est_lat_deg"], abs=1e-9)
    assert state["est_lon_deg"] == pytest.approx(last["est_lon_deg"], abs=1e-9)
    assert 0.0 < state["est_sigma_m"] < 50_000.0 and all(math.isfinite(v) for v in state["est_cov_en_m2"])
    assert {s["name"] for s in state["sensors"]} >= {"magnetometer", "attitude", "FC heartbeat"}
    assert any("step 1 phase probe2" in text for text in state["statustexts"])
    assert any("GUIDED" in text for text in state["fc_statustexts"])      # the stand-in's, relayed
    status, headers, body = vehicle.get("/")
    page = body.decode()
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert f"running / cruise, mission 1 step {int(last['step'])}" in page
    assert f"{last['est_lat_deg']:.6f}, {last['est_lon_deg']:.6f}" in page
    assert page.count("<svg") == 2 and "<script" not in page and "http://" not in page.replace(
        'xmlns="http://www.w3.org/2000/svg"', "")   # nothing fetched from elsewhere
    assert "step 1 phase probe2" in page and 'href="/records/steps.csv"' in page
    assert '<div class="banner">FAILSAFE: heartbeat: flight controller silent' in page   # the stand-in is gone
    # the records: listed, and downloaded as they are on disk
    status, _, body = vehicle.get("/records/")
    names = {f["name"] for f in json.loads(body)}
    assert status == 200 and {"steps.csv", "companion.tlog"} <= names
    status, headers, body = vehicle.get("/records/steps.csv")
    assert status == 200 and body == (vehicle.records / "steps.csv").read_bytes()
    assert headers["Content-Disposition"] == "attachment; filename*=UTF-8''steps.csv"
    status, headers, body = vehicle.get("/records/companion.tlog", method="HEAD")
    assert status == 200 and body == b"" and int(headers["Content-Length"]) > 100_000
    assert b"status page not updated" not in (vehicle.base / "companion.err").read_bytes()


def _colour_pixels(image: np.ndarray, colour: str, tol: float = 12.0) -> int:
    rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=float)
    return int((np.abs(image[..., :3] * 255.0 - rgb).max(axis=-1) <= tol).sum())


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (Debian: apt-get install chromium); "
                                             "CI installs it in .ci/run")
def test_headless_chromium_shows_the_plot(vehicle, tmp_path):
    from matplotlib.image import imread

    shot = tmp_path / "page.png"
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                        "--disable-background-networking", "--disable-component-update", "--disable-sync",
                        f"--user-data-dir={profile}", f"--screenshot={shot}", "--window-size=1200,900",
                        f"http://127.0.0.1:{vehicle.port}/"],
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=HANG_S, check=True)
    image = imread(shot)
    assert image.shape[:2] == (900, 1200)
    # the plot's colours: the estimate and its track, the ellipse's outline, the destination
    counts = {name: _colour_pixels(image, colour) for name, colour in
              (("track", TRACK_COLOUR), ("ellipse", ELLIPSE_COLOUR), ("destination", DEST_COLOUR))}
    assert all(n >= 100 for n in counts.values()), counts
    assert float((image[..., :3] < 0.5).mean()) > 0.005, "no text"     # not a blank page


def _raw(port: int, data: bytes) -> bytes:
    """Send ``data`` on a fresh connection; what came back until the server closed or went quiet."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        try:
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass   # the server closed on an oversized request while it was still being sent
        chunks = []
        try:
            while chunk := sock.recv(65536):
                chunks.append(chunk)
        except OSError:
            pass
    return b"".join(chunks)


TRAVERSALS = ["/records/../../etc/passwd", "/records/%2e%2e/%2e%2e/etc/passwd", "/records/..%2f..%2fetc%2fpasswd",
              "/records/%2E%2E%2F%2E%2E%2F%2E%2E%2Fetc%2Fpasswd", "/records//etc/passwd", "/records/%2Fetc%2Fpasswd",
              "/records/outside.txt", "/records/link_out", "/records/.hidden",
              "/records/sub/inner.txt", "/records/sub%2Finner.txt", "/records/steps.csv%00.txt",
              "/../../etc/passwd", "/records/....//....//etc/passwd", "/records/%252e%252e/etc/passwd",
              "/records/" + "../" * 40 + "etc/passwd", "/records/link_dir/" + "x"]
METHODS = ["POST", "PUT", "DELETE", "PATCH", "OPTIONS", "PROPFIND", "CONNECT"]


def test_bad_requests_read_nothing_outside_and_change_nothing(vehicle, tmp_path):
    outside = vehicle.base / "outside.txt"
    outside.write_text(SECRET, encoding="utf-8")
    records = vehicle.records
    (records / "link_out").symlink_to(outside)
    (records / "link_dir").symlink_to(vehicle.base)
    (records / ".hidden").write_text(SECRET, encoding="utf-8")
    (records / "sub").mkdir()
    (records / "sub" / "inner.txt").write_text(SECRET, encoding="utf-8")
    before = vehicle.state()
    parm_before = (vehicle.base / "companion.parm").read_bytes()
    steps_before = (records / "steps.csv").read_bytes()
    secrets = (SECRET.encode(), b"root:")

    status, _, body = vehicle.get("/records/")
    assert status == 200 and {f["name"] for f in json.loads(body)} & {
        "link_out", "link_dir", ".hidden", "sub"} == set()
    for path in TRAVERSALS:
        status, _, body = vehicle.get(path)
        assert status in (400, 404), (path, status)
        assert not any(s in body for s in secrets), path
    for method in METHODS:
        for path in ("/", "/state.json", "/records/steps.csv", "/records/", "/nowhere"):
            status, headers, body = vehicle.get(path, method=method, body=b"NAV_SPEED_KMH=99",
                                                headers={"Content-Type": "application/x-www-form-urlencoded"})
            assert status in (400, 405), (method, path, status)
            assert status == 400 or headers.get("Allow") == "GET, HEAD", (method, path, headers)
    oversized_and_malformed = [
        b"GET /" + b"A" * 200_000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",                   # request line
        b"GET / HTTP/1.1\r\nHost: x\r\n" + b"X-Pad: " + b"B" * 200_000 + b"\r\n\r\n",  # one header
        b"GET / HTTP/1.1\r\nHost: x\r\n" + b"".join(b"X-%d: y\r\n" % i for i in range(20_000)) + b"\r\n",
        b"POST /records/steps.csv HTTP/1.1\r\nHost: x\r\nContent-Length: 50000000\r\n\r\n" + b"C" * 100_000,
        b"POST / HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n" + b"10000\r\n" + b"D" * 65536 + b"\r\n" * 2,
        b"GARBAGE\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n", b"\x00\xff\xfe\r\n\r\n", b"GET /\r\n\r\n",
        b"GET / HTTP/1.1\r\nno colon here\r\n\r\n", b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: -5\r\n\r\n",
        b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n",
        b"GET /records/../../etc/passwd HTTP/1.0\r\n\r\n", b"GET /records/%2e%2e/%2e%2e/etc/passwd HTTP/1.1\r\n\r\n",
        b"GET http://127.0.0.1/../../etc/passwd HTTP/1.1\r\nHost: x\r\n\r\n",
        b"GET / HTTP/1.1\r\nHost: x\r\n\r\nGET /records/../../etc/passwd HTTP/1.1\r\n\r\n",   # pipelined
    ]
    for data in oversized_and_malformed:
        answer = _raw(vehicle.port, data)
        first = answer.split(b"\r\n", 1)[0]
        assert not any(s in answer for s in secrets), data[:60]
        if not data.startswith(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"):   # all but the pipelined one: no 200
            assert b" 200 " not in first, (data[:60], first)
    # a flood of idle connections: those beyond MAX_CONNECTIONS are closed at once
    flood = [socket.create_connection(("127.0.0.1", vehicle.port), timeout=10) for _ in range(MAX_CONNECTIONS + 8)]
    try:
        closed = 0
        for sock in flood[MAX_CONNECTIONS:]:
            sock.settimeout(5.0)
            try:
                closed += sock.recv(1) == b""
            except ConnectionResetError:
                closed += 1
            except TimeoutError:
                pass        # still open
        assert closed == 8
    finally:
        for sock in flood:
            sock.close()
    # the server still answers once it has seen the flood close, the companion runs, and nothing it
    # holds has changed
    deadline = time.monotonic() + 30.0
    while True:
        try:
            after = vehicle.state()
            break
        except ConnectionError:
            assert time.monotonic() < deadline, "the server did not answer after the flood"
            time.sleep(0.05)   # the polling interval
    assert vehicle.companion.poll() is None
    keys = ("state", "phase", "mission", "step", "restarts", "est_lat_deg", "est_lon_deg", "est_sigma_m",
            "dest_lat_deg", "dest_lon_deg", "msg_time_s")
    assert {k: after[k] for k in keys} == {k: before[k] for k in keys}
    assert (vehicle.base / "companion.parm").read_bytes() == parm_before
    assert (records / "steps.csv").read_bytes() == steps_before
    status, _, _ = vehicle.get("/")
    assert status == 200
    said = (vehicle.base / "companion.err").read_bytes()     # --quiet: only what went wrong
    assert b"Traceback" not in said and b"Uncaught" not in said and b"ERROR" not in said, said[-2000:]


# --- the parts, without processes -----------------------------------------------------------------
def test_the_ellipse_holds_95_percent_of_its_gaussian():
    """Points on the drawn ellipse lie at the 95 % chi-square distance of the covariance, and
    95 % of a seeded sample of that Gaussian falls inside (binomial 3-sigma over 20,000 draws)."""
    cov = np.array([[900.0 ** 2, 0.6 * 900.0 * 300.0], [0.6 * 900.0 * 300.0, 300.0 ** 2]])
    e = ellipse_95((cov[0, 0], cov[0, 1], cov[1, 1]), math.nan)
    t = np.linspace(0.0, 2.0 * math.pi, 36)
    c, s = math.cos(e.angle_rad), math.sin(e.angle_rad)
    pts = np.stack([e.major_m * np.cos(t) * c - e.minor_m * np.sin(t) * s,
                    e.major_m * np.cos(t) * s + e.minor_m * np.sin(t) * c])
    d2 = np.einsum("ij,ij->j", pts, np.linalg.solve(cov, pts))
    assert np.allclose(d2, 5.991464547107979, rtol=1e-9)
    draws = np.random.default_rng(0).multivariate_normal([0.0, 0.0], cov, size=20_000)
    along = draws @ np.array([c, s])
    across = draws @ np.array([-s, c])
    inside = float(np.mean((along / e.major_m) ** 2 + (across / e.minor_m) ** 2 <= 1.0))
    assert abs(inside - 0.95) <= 3.0 * math.sqrt(0.95 * 0.05 / 20_000)
    assert ellipse_95((math.nan,) * 3, 100.0).major_m == pytest.approx(244.77, abs=0.01)   # sqrt(5.991) sigma
    assert ellipse_95((math.nan,) * 3, math.nan) is None


def test_http_address_forms():
    assert parse_http_address("8080") == ("127.0.0.1", 8080)                  # a port alone: loopback
    assert parse_http_address("0.0.0.0:8080") == ("0.0.0.0", 8080)
    assert parse_http_address("[::1]:81") == ("::1", 81)
    for bad in ("", "host:", ":80", "80000", "host:0", "host:x"):
        with pytest.raises(ValueError, match="--http"):
            parse_http_address(bad)


def test_track_reader_reads_on_and_never_a_half_written_line(tmp_path):
    path = tmp_path / "steps.csv"
    recorder = StepRecorder(path)
    reader = TrackReader(path)
    assert reader.read().est_lat_deg == ()
    recorder.write({"event": "start", "est_lat_deg": 9.0})
    recorder.write({"event": "step", "est_lat_deg": 1.0, "est_lon_deg": 2.0, "fix_lat_deg": 1.5})
    row = [""] * len(STEP_COLUMNS)
    row[STEP_COLUMNS.index("est_lat_deg")], row[STEP_COLUMNS.index("est_lon_deg")] = "3.0", "4.0"
    row[STEP_COLUMNS.index("event")] = "step"
    line = ",".join(row) + "\n"
    with open(path, "a", encoding="utf-8") as handle:              # the writer caught mid-row
        handle.write(line[:len(line) // 2])
    track = reader.read()
    assert track.est_lat_deg == (1.0,) and track.est_lon_deg == (2.0,) and math.isnan(track.fix_lon_deg[0])
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(line[len(line) // 2:])                        # the row completed
    assert reader.read().est_lat_deg == (1.0, 3.0) and reader.read().est_lon_deg == (2.0, 4.0)
    recorder.close()
    StepRecorder(path).close()                                      # a new file (a restart): read afresh
    assert reader.read().est_lat_deg == ()

"""sitl.fc.cli and sitl.fc.records: runs of ``python -m sitl.fc``: reproducible per seed, the truth log, errors exit 2, SIGTERM keeps the records."""
from __future__ import annotations

import numpy as np
import pytest

from sitl.fc import main
from sitl.truthlog import TRUTH_COLUMNS, read_truth_csv
from tests.sitl.conftest import REPO, open_client, read_tlog, run_cli
from tests.sitl.fc.helpers import closed_udp_port


def test_runs_are_reproducible_for_a_seed(tmp_path):
    port = closed_udp_port()
    args = ["--speedup", "0", "--duration", "30", "--tlog", "--out", f"udp:127.0.0.1:{port}", "--fault",
            "link_loss:5:10:0.3"]
    runs = []
    for k, seed in enumerate((7, 7, 8)):
        folder = tmp_path / f"r{k}"
        folder.mkdir()
        _, log_dir = run_cli(args + ["--seed", str(seed)], folder)
        runs.append(((log_dir / "truth.csv").read_bytes(), (log_dir / "sitl.tlog").read_bytes()))
    assert runs[0] == runs[1]
    assert runs[0][0] != runs[2][0] and runs[0][1] != runs[2][1]


def test_truth_log_columns_and_fc_drift(tmp_path):
    _, log_dir = run_cli(["--speedup", "0", "--duration", "1800", "--out", f"udp:127.0.0.1:{closed_udp_port()}"],
                         tmp_path)
    log = read_truth_csv(log_dir / "truth.csv")
    assert tuple(log) == TRUTH_COLUMNS
    assert len(log["time_s"]) == 1801                          # 0..1800 s at 1 Hz (the final row is t = 1800)
    err = np.hypot(log["fc_err_e_m"], log["fc_err_n_m"])
    assert err[0] > 100.0 and np.all(np.isfinite(err))          # Table 1: km-scale initial INS error
    assert np.ptp(err) > 1.0                                    # and it drifts
    assert log["remaining_m"][0] == pytest.approx(799_071.9, abs=1.0)
    assert set(log["gps_fix"]) == {0.0}                         # pacific denies GPS from t = 0


def test_cli_errors_exit_2(capsys):
    assert main(["--scenario", "no_such_scenario", "--quiet"]) == 2
    assert "no scenario" in capsys.readouterr().err
    assert main(["--fault", "mag_explode:1", "--quiet", "--no-truth-log"]) == 2
    assert main(["--out", "serial:/dev/null", "--quiet", "--no-truth-log"]) == 2
    assert main(["--fault", "storm_onset:5", "--quiet", "--no-truth-log"]) == 2   # pacific has no storm
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:
        main(["--space-weather-feed", "NAV_KP,NAV_DST", "--quiet"])
    assert refused.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        "fcmpc-sitl: error: argument --space-weather-feed: unknown space-weather reading NAV_DST: choose from "
        "NAV_KP, NAV_SYMH (see fcmpc-sitl --help)"]


def test_sigterm_stops_cleanly_and_flushes_records(tmp_path):
    import json
    import os
    import signal
    import subprocess
    import sys

    log_dir = tmp_path / "sig"
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    client, port = open_client()
    proc = subprocess.Popen([sys.executable, "-m", "sitl.fc", "--speedup", "50", "--tlog", "--log-dir",
                             str(log_dir), "--out", f"udp:127.0.0.1:{port}"],
                            env=env, stderr=subprocess.PIPE)
    try:
        # stopped once the simulator's own clock says 15 s (its SYSTEM_TIME), whatever the machine's load
        client.recv("SYSTEM_TIME", 60.0, predicate=lambda m: m.time_boot_ms >= 15_000)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    finally:
        client.conn.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads((log_dir / "summary.json").read_text())
    assert 10.0 < summary["sim_s"] < 500.0
    log = read_truth_csv(log_dir / "truth.csv")
    assert log["time_s"][-1] == pytest.approx(summary["sim_s"])
    assert len(read_tlog(log_dir / "sitl.tlog")) == summary["tx_messages"]
    assert b"simulated in" in err

"""scripts/calibrate.py is a thin entry point: run as its own process, it is fcmpc-calibrate."""
from __future__ import annotations

import subprocess
from pathlib import Path

from tests.scripts.test_replay import REPO
from tests.scripts.test_replay import _run as _run_module

CURRENT_ULOG = REPO / "tests" / "data" / "ulog" / "px4-2021-sensor-mag.ulg"


def _run(*args: str) -> subprocess.CompletedProcess:
    return _run_module(*args, script="calibrate.py")


def test_a_user_error_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    path = tmp_path / "notalog.bin"
    path.write_bytes(b"not a flight log\n" * 10)
    done = _run(str(path), "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fcmpc-calibrate: ") and str(path) in lines[0]
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


def test_a_refused_calibration_is_one_line_with_its_reasons(tmp_path: Path) -> None:
    """6 s on the ground: too few directions for either fit; nothing written."""
    done = _run(str(CURRENT_ULOG), "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert "sphere's 72 cells" in line and "1 of 12 sectors" in line
    assert not (tmp_path / "out").exists()


"""scripts/replay.py is a thin entry point: run as its own process, it is fcmpc-replay."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _run(*args: str, script: str = "replay.py") -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, f"scripts/{script}", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO)))


def test_a_user_error_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    path = tmp_path / "notalog.bin"
    path.write_bytes(b"not a flight log\n" * 10)
    done = _run(str(path), "--no-plots", "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fcmpc-replay: ") and str(path) in lines[0]
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


def test_help_names_every_log_format() -> None:
    done = _run("--help")
    assert done.returncode == 0
    for words in (".bin", ".tlog", ".ulg", ".csv", "--date"):
        assert words in done.stdout

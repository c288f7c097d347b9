"""``module load fcmpc`` finds the tools' package itself; its ``init`` imports MAVProxy only when
MAVProxy calls it, so the other tools run where MAVProxy is not installed."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_package_is_mavproxys_entry_and_the_tools_never_import_mavproxy():
    program = ("import sys, fcmpc, fcmpc.montecarlo, fcmpc.montecarlo.runs\n"
               "assert callable(fcmpc.init)\n"
               "print(sorted(m for m in sys.modules if m.split('.')[0] == 'MAVProxy'))")
    done = subprocess.run([sys.executable, "-c", program], cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout

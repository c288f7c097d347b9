"""One policy for the console scripts: a user's mistake is one line naming the option, file or
line, exit status 2, nothing written; a traceback is only for a bug. Each script runs as its own
process, as a user starts it."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.cli import ArgumentParser, UsageError, one_line, param_items, run_main

REPO = Path(__file__).resolve().parents[1]
MODULES = {"fcmpc-fly": "fcmpc.fly.cli", "fcmpc-sitl": "sitl.fc", "fcmpc-companion": "companion.app",
           "fcmpc-montecarlo": "fcmpc.montecarlo.cli", "fcmpc-bench": "fcmpc.bench.cli"}


def _run(prog: str, argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1")
    return subprocess.run([sys.executable, "-m", MODULES[prog], *argv], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


@pytest.fixture
def bad_parm(tmp_path) -> Path:
    path = tmp_path / "bad.parm"
    path.write_text("NAV_SPEED_KMH 40\nNAV_SPEDD_KMH 45\n", encoding="utf-8")
    return path


CASES = [
    ("fcmpc-fly", ["--scenario", "pacifc"], "'pacifc'"),
    ("fcmpc-fly", ["--param", "NAV_SPEED_KMH=fast"], "--param NAV_SPEED_KMH=fast"),
    ("fcmpc-fly", ["--short", "--short-km", "-5"], "--short-km"),
    ("fcmpc-fly", ["--sped", "3"], "--sped"),
    ("fcmpc-sitl", ["--scenario", "pacifc"], "'pacifc'"),
    ("fcmpc-sitl", ["--fault", "mag_of:10"], "mag_of:10"),
    ("fcmpc-sitl", ["--sped", "3"], "--sped"),
    ("fcmpc-sitl", ["--speedup", "fast"], "--speedup"),
    ("fcmpc-companion", ["--params", "missing.parm"], "missing.parm"),
    ("fcmpc-companion", ["--param-encoding", "nonsense"], "--param-encoding"),
    ("fcmpc-companion", ["--http", "board:http"], "--http 'board:http'"),
    ("fcmpc-montecarlo", ["--scenario", "pacifc"], "'pacifc'"),
    ("fcmpc-montecarlo", ["--params", "missing.parm"], "missing.parm"),
    ("fcmpc-montecarlo", ["--params", "{bad_parm}"], "bad.parm:2"),
    ("fcmpc-montecarlo", ["--runs", "0"], "--runs"),
    ("fcmpc-montecarlo", ["--param", "MPC_S_AUTO=0", "--param", "NAV_DEST_LAT=-30"], "MPC_S_MIN_I"),   # Table 4 bounds refuse it
    ("fcmpc-bench", ["--quik"], "--quik"),
    ("fcmpc-bench", ["--repeat", "0"], "--repeat"),
]


@pytest.mark.parametrize("prog,argv,names", CASES, ids=[f"{c[0]} {' '.join(c[1])}" for c in CASES])
def test_user_error_is_one_line_and_exit_2(tmp_path, bad_parm, prog, argv, names):
    argv = [a.replace("{bad_parm}", str(bad_parm)) for a in argv]
    before = set(tmp_path.rglob("*"))
    result = _run(prog, argv + (["--out-dir", str(tmp_path / "run")] if prog == "fcmpc-fly" else []), tmp_path)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: ") and names in lines[0], result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""
    assert set(tmp_path.rglob("*")) == before          # nothing written: no empty out/ folder


def test_help_states_defaults_once_and_does_not_contradict_itself():
    for prog in ("fcmpc-fly", "fcmpc-companion", "fcmpc-montecarlo"):
        text = " ".join(_run(prog, ["--help"], REPO).stdout.split())
        assert "(default: False)" not in text and "(default: None)" not in text, prog
        for option in text.split(" --")[1:]:
            assert option.count("default") <= 1, f"{prog}: --{option}"


# --- the helper itself --------------------------------------------------------------------------
def test_run_main_maps_user_errors_interrupts_and_bugs(capsys):
    assert run_main("prog", lambda: 0) == 0
    assert run_main("prog", lambda: (_ for _ in ()).throw(UsageError("--x 3: too big"))) == 2
    assert capsys.readouterr().err == "prog: --x 3: too big\n"
    assert run_main("prog", lambda: open("/nonexistent/x.parm")) == 2
    assert capsys.readouterr().err == "prog: /nonexistent/x.parm: No such file or directory\n"
    assert run_main("prog", lambda: (_ for _ in ()).throw(KeyboardInterrupt())) == 130
    with pytest.raises(ZeroDivisionError):              # a bug keeps its traceback
        run_main("prog", lambda: 1 // 0)


def test_parser_error_is_one_line(capsys):
    parser = ArgumentParser(prog="prog")
    parser.add_argument("--n", type=int)
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--n", "x"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("prog: error: argument --n") and "--help" in err


def test_param_items_validate_against_the_registry():
    assert param_items(["nav_speed_kmh=40"]) == {"NAV_SPEED_KMH": 40.0}
    for bad, named in (("NAV_SPEED_KMH=0", "out of range"), ("NOPE=1", "unknown"), ("=1", "NAME=VALUE")):
        with pytest.raises(UsageError, match=named):
            param_items([bad])
    assert one_line(ValueError("a\n  b")) == "a b"

"""Every file in scripts/ works as ``python scripts/X.py`` and as its console script, and the two
print the same help: real processes, started side by side (18 of them: about 10 s of CPU).

The console script is the installed wrapper when the installed entry points are this checkout's
(CI's fresh ``pip install -e .``); otherwise the same two lines pip's wrapper runs
(``from MODULE import main; sys.exit(main())``), so a stale install elsewhere cannot hide a break.
"""
from __future__ import annotations

import configparser
import os
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = sorted((REPO / "scripts").glob("*.py"))
THIN = re.compile(r'^"""[^"]+"""\nimport sys\n\nfrom (fcmpc(?:\.\w+)+) import main\n\n'
                  r'if __name__ == "__main__":\n    sys.exit\(main\(\)\)\n$')


def _console_scripts() -> dict[str, str]:
    """setup.cfg's console scripts: name -> ``module:function``."""
    cfg = configparser.ConfigParser()
    cfg.read(REPO / "setup.cfg", encoding="utf-8")
    lines = cfg["options.entry_points"]["console_scripts"].strip().splitlines()
    return dict(tuple(part.strip() for part in line.split("=")) for line in lines)


def _installed() -> dict[str, str]:
    try:
        return {ep.name: ep.value for ep in metadata.distribution("fcmpc").entry_points if ep.group == "console_scripts"}
    except metadata.PackageNotFoundError:
        return {}


def test_every_script_is_thin_and_has_its_console_script():
    declared = {target.split(":")[0]: name for name, target in _console_scripts().items()}
    for script in SCRIPTS:
        found = THIN.match(script.read_text(encoding="utf-8"))
        assert found, f"{script.name}: not a docstring + 'from fcmpc.X import main' + the __main__ guard"
        assert found.group(1) in declared, f"{script.name}: {found.group(1)}:main is no console script in setup.cfg"
    tools = {target for target in _console_scripts().values() if target.startswith("fcmpc")}
    scripted = {THIN.match(s.read_text(encoding="utf-8")).group(1) + ":main" for s in SCRIPTS}
    assert tools == scripted, f"console scripts without a file in scripts/: {sorted(tools - scripted)}"


def test_each_script_and_its_console_script_print_the_same_help(tmp_path):
    consoles = _console_scripts()
    installed = _installed()
    bin_dir = Path(sys.executable).parent
    env = dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1")
    runs: dict[tuple[str, str], subprocess.Popen] = {}
    for script in SCRIPTS:
        module = THIN.match(script.read_text(encoding="utf-8")).group(1)
        name = next(n for n, target in consoles.items() if target == f"{module}:main")
        wrapper = bin_dir / name
        if installed.get(name) == consoles[name] and wrapper.exists():
            console = [str(wrapper), "--help"]
        else:   # what pip's wrapper runs
            console = [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())", "--help"]
        # the script as the docs show it, from the repository; the console script from elsewhere (a
        # module that needs the repository as its working folder fails there, whichever way it starts)
        ways = {"script": ([sys.executable, f"scripts/{script.name}", "--help"], REPO), "console": (console, tmp_path)}
        for way, (argv, cwd) in ways.items():
            runs[(script.name, way)] = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                                        stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    results = {key: (proc.communicate(timeout=300), proc.returncode) for key, proc in runs.items()}
    for script in SCRIPTS:
        (help_text, err), code = results[(script.name, "console")]
        assert code == 0 and help_text.startswith("usage: fcmpc-") and not err, f"{script.name} console: {err}"
        (out, err), code = results[(script.name, "script")]
        assert code == 0 and not err, f"python scripts/{script.name} --help: exit {code}\n{err}"
        assert out == help_text, f"python scripts/{script.name} --help differs from the console script"

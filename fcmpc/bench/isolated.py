"""Benchmark sections run each in a fresh interpreter, from a given source tree.

A section timed in the process that has just run others is slower than alone: the Fc-MPC mission
step measured 8-10 % slower right after the QP's and the field's sections than in a fresh
process (2026-12-05, two rounds), and `fcmpc-bench --reference HEAD` set the code 0.86x against
itself while ours ran in the bench's own process and the reference's in a child. So every
section, ours and a reference commit's alike, runs in a child interpreter of its own (this
interpreter, ``PYTHONPATH`` the tree, so the tree's packages are the ones imported) and sends
its rows back as JSON.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from fcmpc.bench.sections import Row

__all__ = ["SectionRunError", "run_sections", "sections_module"]

_PROGRAM = """
import importlib, json, sys
bench = importlib.import_module(sys.argv[1])
rows = []
for name in sys.argv[2:]:
    try:
        rows += [[str(v) for v in r] for r in getattr(bench, name)()]
    except Exception as err:
        rows.append([name, "FAILED: %s: %s" % (type(err).__name__, err)])
print(json.dumps(rows))
"""


class SectionRunError(RuntimeError):
    """The child interpreter did not run the sections (the message says why)."""


def sections_module(tree: Path) -> str:
    """Where ``tree`` keeps its benchmark functions (``fcmpc/bench/``; before it ``fcmpc_bench/``, and
    before that ``scripts/bench.py``)."""
    for module in ("fcmpc.bench.sections", "fcmpc_bench.sections"):
        if (tree / module.replace(".", "/")).with_suffix(".py").exists():
            return module
    return "scripts.bench"


def run_sections(tree: Path, sections: list[str], timeout_s: float = 1800.0) -> list[Row]:
    """Run the benchmark functions named ``sections`` of the source ``tree`` in a fresh
    interpreter: their rows (benchmark, figure, anchor, target; a section that raised is one
    row whose figure starts ``FAILED``). Raises :class:`SectionRunError` when the interpreter
    itself fails, ``subprocess.TimeoutExpired`` after ``timeout_s``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    ran = subprocess.run([sys.executable, "-c", _PROGRAM, sections_module(tree), *sections], cwd=tree, env=env,
                         capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL)
    if ran.returncode != 0 or not ran.stdout.strip():
        last = (ran.stderr.strip().splitlines() or ["no output"])[-1]
        raise SectionRunError(f"the benchmarks of {tree} failed: {last}")
    rows = json.loads(ran.stdout.strip().splitlines()[-1])
    return [(*row, "", "", "")[:4] for row in rows]

"""An earlier commit's benchmarks, measured in the same run as ours (``fcmpc-bench --reference``).

This shared machine's speed moves 2-3x between days (pygeomag's time per point: 66-271 us), so
a figure measured on another day says little about whether our code got faster. The code the
issue's "today" figures were measured on, run minutes apart on the same machine, does: the
commit is checked out into a temporary git worktree, its own benchmark functions run there in
a child process (:mod:`fcmpc.bench.isolated`, as ours are), section by section right after
ours, and its figures come back as numbers by row name.

:data:`REFERENCE_COMMIT` is the README's table before issue 13 (2026-11-22), whose figures are
the issue's "today". Its ``Fc-MPC`` mission step is the paper's estimator (Table 3 fusion on
(D, I)); ours is compared on the same workload (:data:`SAME_WORKLOAD`), and the default
navigator's step, which also runs the error-state filter of issue 14, is shown beside it.
"""
from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

from fcmpc.bench.isolated import SectionRunError, run_sections
from fcmpc.bench.sections import Row
from fcmpc.bench.table import format_rows, leading_number

__all__ = ["ISSUE_SPEEDUP", "REFERENCE_COMMIT", "SAME_WORKLOAD", "WIDER_WORK", "ReferenceRunError", "ReferenceTree",
           "compare", "format_comparison", "resolve"]

REFERENCE_COMMIT = "9a267ba"
REPO = Path(__file__).resolve().parents[2]

# our row -> the reference's row measuring the same work (otherwise rows pair by name)
SAME_WORKLOAD = {"mission step (cruise), Fc-MPC, the paper's estimator": "mission step (cruise), Fc-MPC"}

# rows whose work grew after the reference: said beside the figure
WIDER_WORK = {
    "mission step (cruise), Fc-MPC": "ours runs the error-state filter too (issue 14)",
    "mission step (cruise), Fc-MPC, fusing every step": "ours runs the error-state filter too (issue 14)",
    "companion capacity_msgs_per_s": "ours feeds the flight controller a 10 Hz position and reads through the link's "
                                     "peers and tlog (issue 49)",
}

# the speed-up issue 13 asks for: its "today" figure over its target (higher is faster for the simulator)
ISSUE_SPEEDUP = {
    "MPC update+solve, osqp (N=2)": 59.0 / 40.0,
    "mission step (cruise), Fc-MPC, the paper's estimator": 862.0 / 400.0,
    "Monte Carlo, 50 runs x 3 controllers": 22.5 / 10.0,
    "SITL speed-up over real time": 2000.0 / 1208.0,
}

class ReferenceRunError(RuntimeError):
    """The reference commit could not be checked out or benchmarked (the message says which)."""


def resolve(commit: str) -> str:
    """The full hash of ``commit`` in this repository; :class:`ReferenceRunError` when it names none
    (checked before the benchmarks run, so a typo costs no minutes)."""
    found = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}"],
                           capture_output=True, text=True)
    if found.returncode != 0 or not found.stdout.strip():
        raise ReferenceRunError(f"--reference {commit!r}: no such commit in {REPO}")
    return found.stdout.strip()


class ReferenceTree:
    """``commit`` checked out into a temporary worktree for as long as the ``with`` block lasts;
    :meth:`run` times one of its benchmark sections there. Raises :class:`ReferenceRunError` when
    the commit cannot be checked out."""

    def __init__(self, commit: str, timeout_s: float = 1800.0) -> None:
        self.commit, self.timeout_s = commit, timeout_s
        self._tmp: tempfile.TemporaryDirectory | None = None
        self.tree = Path()

    def __enter__(self) -> ReferenceTree:
        self._tmp = tempfile.TemporaryDirectory(prefix="fcmpc-bench-reference-")
        self.tree = Path(self._tmp.name) / "tree"
        added = subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "--quiet", str(self.tree),
                                self.commit], capture_output=True, text=True)
        if added.returncode != 0:
            self._tmp.cleanup()
            raise ReferenceRunError(f"cannot check out {self.commit!r}: {added.stderr.strip() or 'git failed'}")
        return self

    def __exit__(self, *exc) -> None:
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(self.tree)], capture_output=True)
        if self._tmp is not None:
            self._tmp.cleanup()
        # a worktree git could not remove is gone with the folder: forget it too
        subprocess.run(["git", "-C", str(REPO), "worktree", "prune"], capture_output=True)

    def run(self, sections: list[str]) -> dict[str, float]:
        """Run ``sections`` (benchmark function names, e.g. ``bench_mission_step``) of the commit:
        {row name: its leading number}, rows that failed or print no number left out. Raises
        :class:`ReferenceRunError` when its benchmarks do not run."""
        try:
            rows = run_sections(self.tree, sections, self.timeout_s)
        except SectionRunError as err:
            raise ReferenceRunError(f"{self.commit}'s benchmarks failed: {err}") from err
        figures = {name: leading_number(value) for name, value, _, _ in rows}
        return {name: value for name, value in figures.items() if value is not None}


def _issue_speedup(name: str) -> float | None:
    return next((v for k, v in ISSUE_SPEEDUP.items() if name.startswith(k)), None)


def _direction(name: str, figure: str) -> str | None:
    """"time" (lower is faster), "rate" (higher is faster) or None (not a speed: counts, losses)."""
    if "speedup" in name or "speed-up" in name or "msgs_per_s" in name:
        return "rate"
    if (" us" in figure or " s wall" in figure) or ("latency" in name and name.endswith("_ms")):
        return "time"
    return None


def compare(ours: list[Row], theirs: dict[str, float], issue_reference: bool) -> list[Row]:
    """Rows of (benchmark, ours, the reference's figure, our speed-up over it): each of our rows
    that measures a speed and has a reference row of the same name. Against the issue's commit
    (``issue_reference``: :data:`REFERENCE_COMMIT`) rows also pair by work (:data:`SAME_WORKLOAD`)
    and carry the speed-up the issue asks for; against any other commit those would be wrong
    (its Fc-MPC row is already ours), so rows pair by name alone."""
    out: list[Row] = []
    for name, figure, _, _ in ours:
        mine = leading_number(figure)
        their_name = SAME_WORKLOAD.get(name, name) if issue_reference else name
        direction = _direction(name, figure)
        if mine is None or direction is None or their_name not in theirs:
            continue
        reference = theirs[their_name]
        if mine <= 0.0 or reference <= 0.0:
            continue
        speedup = mine / reference if direction == "rate" else reference / mine
        wanted = _issue_speedup(name) if issue_reference else None
        notes = [f"issue asks {wanted:.2f}x: {'met' if speedup >= wanted else 'not met'}"] if wanted else []
        if issue_reference and name in WIDER_WORK:
            notes.append(WIDER_WORK[name])
        out.append((name, figure.split(" [")[0], f"{reference:g}" + (f" ({their_name})" if their_name != name else ""),
                    "; ".join([f"{speedup:.2f}x", *notes])))
    return out


def format_comparison(rows: list[Row], commit: str) -> str:
    """The comparison as a table under a heading that says what it is."""
    if not rows:
        return f"(no row of {commit} measures the same work as ours)"
    head = ("benchmark", "ours (median)", f"{commit} (same run)", "our speed-up over it")
    return f"Against {commit}, measured in this run:\n" + format_rows(rows, head)

"""fcmpc-bench --reference: an earlier commit's benchmarks run beside ours, compared by work."""
from __future__ import annotations

import subprocess

import pytest

from fcmpc.bench.reference import (ISSUE_SPEEDUP, REPO, ReferenceRunError, ReferenceTree, compare, format_comparison,
                                   resolve)
from fcmpc.bench.cli import main

PAPER_STEP = "mission step (cruise), Fc-MPC, the paper's estimator"


def test_times_compare_theirs_over_ours_and_rates_ours_over_theirs():
    ours = [("MPC update+solve, osqp (N=2)", "37.0 us (p99 78) [36-40, 3 runs]", "", ""),
            ("SITL speed-up over real time (speedup)", "2300.0", "", ""),
            ("companion control_steps", "99", "", "")]                  # a count: not a speed
    theirs = {"MPC update+solve, osqp (N=2)": 74.0, "SITL speed-up over real time (speedup)": 1150.0,
              "companion control_steps": 99.0}
    rows = compare(ours, theirs, issue_reference=True)
    assert [r[0] for r in rows] == [ours[0][0], ours[1][0]]
    assert rows[0][1] == "37.0 us (p99 78)" and rows[0][2] == "74"
    assert rows[0][3] == f"2.00x; issue asks {ISSUE_SPEEDUP[ours[0][0]]:.2f}x: met"
    assert rows[1][3].startswith("2.00x; issue asks 1.66x: met")


def test_the_papers_estimator_is_compared_with_the_reference_fc_mpc_step_and_judged():
    theirs = {"mission step (cruise), Fc-MPC": 960.0}
    fast = compare([(PAPER_STEP, "440.0 us (p99 700)", "", "")], theirs, issue_reference=True)[0]
    slow = compare([(PAPER_STEP, "480.0 us (p99 700)", "", "")], theirs, issue_reference=True)[0]
    assert fast[2] == "960 (mission step (cruise), Fc-MPC)"
    assert fast[3].endswith(": met") and slow[3].endswith(": not met")     # 2.18x against 2.00x, the issue 2.16x
    default = compare([("mission step (cruise), Fc-MPC", "650.0 us", "", "")], theirs, issue_reference=True)[0]
    assert "error-state filter" in default[3]                            # the wider work is said


def test_the_companions_capacity_is_a_rate_compared_with_the_reference_and_its_wider_work_said():
    theirs = {"companion capacity_msgs_per_s": 40000.0}
    [row] = compare([("companion capacity_msgs_per_s", "60000.0", "", "")], theirs, issue_reference=True)
    assert row[2] == "40000" and row[3].startswith("1.50x") and "position" in row[3]


def test_another_commit_pairs_rows_by_name_and_says_nothing_of_the_issue():
    # against a later commit its "Fc-MPC" row is the default navigator's, as ours is: pairing
    # the paper's estimator with it, and the issue's asks, would misjudge the change
    theirs = {"mission step (cruise), Fc-MPC": 650.0, "MPC update+solve, osqp (N=2)": 37.0}
    rows = compare([(PAPER_STEP, "400.0 us", "", ""), ("mission step (cruise), Fc-MPC", "640.0 us", "", ""),
                    ("MPC update+solve, osqp (N=2)", "37.0 us", "", "")], theirs, issue_reference=False)
    assert [r[0] for r in rows] == ["mission step (cruise), Fc-MPC", "MPC update+solve, osqp (N=2)"]
    assert [r[3] for r in rows] == ["1.02x", "1.00x"]


def test_rows_without_a_reference_or_a_number_are_left_out():
    assert compare([("Monte Carlo, 50 runs x 3 controllers (2 workers)", "FAILED: x", "", ""),
                    ("geomagnetic fix, prior 15 km off", "41.0 us", "", "")], {}, issue_reference=True) == []
    assert "no row" in format_comparison([], "c")


def test_an_unknown_commit_is_one_clear_line_and_exit_2_before_anything_runs(capsys):
    assert main(["--quick", "--reference", "no-such-commit-here"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such commit" in err[0]
    with pytest.raises(ReferenceRunError):
        resolve("no-such-commit-here")


def _worktrees() -> str:
    return subprocess.run(["git", "-C", str(REPO), "worktree", "list"], capture_output=True, text=True).stdout


def test_a_commits_own_benchmark_functions_run_in_a_worktree_of_it_that_is_removed_after():
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout: no commit to check out")
    with ReferenceTree(resolve("HEAD")) as tree:
        assert str(tree.tree) in _worktrees()
        figures = tree.run(["bench_mpc"])
        assert tree.run(["no_such_section"]) == {}                  # a failed section: no figure, no crash
    assert set(figures) == {"MPC update+solve, osqp (N=2)", "MPC update+solve, daqp (N=2)"}
    assert all(value > 0.0 for value in figures.values())
    assert str(tree.tree) not in _worktrees() and not tree.tree.exists()

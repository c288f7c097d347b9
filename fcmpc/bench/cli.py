"""``fcmpc-bench``: the benchmarks of :mod:`fcmpc.bench`, printed as a table of medians beside
their anchors (README "Benchmarks").

    fcmpc-bench                 # everything (a few minutes on 2 cores)
    fcmpc-bench --quick         # skip the 150-mission Monte Carlo and the closed-loop parts
    fcmpc-bench --repeat 3      # each part three times in a row: per row the median run, and the range
    fcmpc-bench --reference     # and the pre-issue-13 commit's same parts, each after ours (fcmpc.bench.reference)
"""
from __future__ import annotations

import contextlib
import os
import statistics
import subprocess
import sys
from collections.abc import Callable, Sequence

from companion.cli import ArgumentParser, positive_int, run_main
from fcmpc.bench import QUICK_SECTIONS, SECTIONS, Row, format_rows, median_rows
from fcmpc.bench.isolated import SectionRunError, run_sections
from fcmpc.bench.reference import REFERENCE_COMMIT, REPO, ReferenceRunError, ReferenceTree, compare, \
    format_comparison, resolve


def _ours(section: Callable[[], list[Row]]) -> list[Row]:
    """One of our sections in a fresh interpreter (:mod:`fcmpc.bench.isolated`: what ran before
    in this process would slow it); a failure is its row."""
    try:
        return run_sections(REPO, [section.__name__])
    except (SectionRunError, OSError, ValueError, subprocess.TimeoutExpired) as err:
        return [(section.__name__, f"FAILED: {type(err).__name__}: {err}", "", "")]


def _measure(sections: Sequence[Callable[[], list[Row]]], repeat: int,
             tree: ReferenceTree | None) -> tuple[list[Row], dict[str, list[float]]]:
    """Each section ``repeat`` times, each in a fresh interpreter and each time followed by the
    reference's same section when ``tree`` is given (so the two are minutes apart, alike): our
    median rows, and the reference's figures per row name."""
    rows: list[Row] = []
    theirs: dict[str, list[float]] = {}
    for section in sections:
        runs = []
        for _ in range(repeat):
            runs.append(_ours(section))
            if tree is not None:
                try:
                    for name, value in tree.run([section.__name__]).items():
                        theirs.setdefault(name, []).append(value)
                except (ReferenceRunError, OSError, ValueError, subprocess.TimeoutExpired) as err:
                    print(f"fcmpc-bench: reference {tree.commit[:9]}, {section.__name__}: {err}", file=sys.stderr)
        rows += median_rows(runs)
        print(f"  ... {section.__name__} done", file=sys.stderr)
    return rows, theirs


def _run(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog="fcmpc-bench", description="fcmpc benchmarks (medians)")
    parser.add_argument("--quick", action="store_true", help="skip the Monte Carlo and the closed-loop parts")
    parser.add_argument("--repeat", type=positive_int, default=1,
                        help="run each part N times in a row and print, per row, the median run and the range "
                             "(a shared machine's speed moves between runs minutes apart)")
    parser.add_argument("--reference", nargs="?", const=REFERENCE_COMMIT, default=None, metavar="COMMIT",
                        help="also run COMMIT's same parts (default: %(const)s, the README's figures before issue 13) "
                             "in a temporary worktree, each right after ours, and print our speed-up over it: on a "
                             "machine whose speed moves between days, the comparison that holds")
    args = parser.parse_args(argv)
    reference, issue_reference = None, False
    if args.reference is not None:
        try:
            reference = resolve(args.reference)
        except ReferenceRunError as err:
            print(f"fcmpc-bench: {err}", file=sys.stderr)
            return 2
        with contextlib.suppress(ReferenceRunError):   # a shallow clone may not hold the issue's commit
            issue_reference = reference == resolve(REFERENCE_COMMIT)   # it alone gets the issue's asks
    sections = QUICK_SECTIONS if args.quick else SECTIONS
    with contextlib.ExitStack() as stack:
        tree = None
        if reference is not None:
            try:
                tree = stack.enter_context(ReferenceTree(reference))
            except ReferenceRunError as err:
                print(f"fcmpc-bench: {err}", file=sys.stderr)
                return 2
        rows, theirs = _measure(sections, args.repeat, tree)
    print(format_rows(rows))
    if reference is not None:
        medians = {name: statistics.median_low(values) for name, values in theirs.items()}
        print("\n" + format_comparison(compare(rows, medians, issue_reference), args.reference))
    print(f"\n(load average {', '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores: "
          "on a shared machine the absolute figures are indicative, the ratios to an anchor of the same run "
          "are the robust ones)")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-bench", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())

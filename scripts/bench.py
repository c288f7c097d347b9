"""``fcmpc-bench``: the benchmarks of :mod:`fcmpc_bench`, printed as a table of medians beside
their anchors (README "Benchmarks").

    fcmpc-bench                 # everything (a few minutes on 2 cores)
    fcmpc-bench --quick         # skip the 150-mission Monte Carlo and the closed-loop parts
    fcmpc-bench --repeat 3      # each part three times in a row: per row the median run, and the range
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):   # before numpy loads
    os.environ.setdefault(_var, "1")

import sys

from companion.cli import ArgumentParser, positive_int, run_main
from fcmpc_bench import QUICK_SECTIONS, SECTIONS, Row, format_rows, median_rows


def _run(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog="fcmpc-bench", description="fcmpc benchmarks (medians)")
    parser.add_argument("--quick", action="store_true", help="skip the Monte Carlo and the closed-loop parts")
    parser.add_argument("--repeat", type=positive_int, default=1,
                        help="run each part N times in a row and print, per row, the median run and the range "
                             "(a shared machine's speed moves between runs minutes apart)")
    args = parser.parse_args(argv)
    rows: list[Row] = []
    for section in QUICK_SECTIONS if args.quick else SECTIONS:
        runs = []
        for _ in range(args.repeat):
            try:
                runs.append(section())
            except Exception as err:  # noqa: BLE001 -- a missing part must not hide the others' numbers
                runs.append([(section.__name__, f"FAILED: {type(err).__name__}: {err}", "", "")])
        rows += median_rows(runs)
        print(f"  ... {section.__name__} done", file=sys.stderr)
    print(format_rows(rows))
    print(f"\n(load average {', '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores: "
          "on a shared machine the absolute figures are indicative, the ratios to an anchor of the same run "
          "are the robust ones)")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-bench", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())

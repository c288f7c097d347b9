"""The published results: each row one ``fcmpc-montecarlo`` command, run and tabulated.

``fcmpc-results`` runs every row of :data:`ROWS` through the Monte Carlo's own command line (so a
published figure is exactly what that command prints), writes ``docs/results.md`` with the
commands, the commit and the date, and puts the same tables into the README between its
``<!-- results:NAME -->`` markers. Nothing here computes a figure of its own: the numbers are the
``summary.json`` each command writes.

Seeds: every row flies seeds FIRST_SEED..FIRST_SEED+runs-1, outside the seeds 0-99 on which earlier
work chose navigator defaults (the heading-state and model-error priors were swept on the realistic
Pacific's seeds 0-49 and 50-99: docs/notes/). No row's world set a parameter it is scored with: the
navigator's defaults come from the registry, and the scenarios carry no values fitted on their own
truth (``tests/sitl/test_scenarios_honest.py``).
"""
from __future__ import annotations

import json
import math
import re
import subprocess
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["Row", "ROWS", "run_row", "render", "splice_readme", "main"]


@dataclass(frozen=True)
class Row:
    """One published figure: the table it belongs to, its label, and the command's arguments."""

    table: str          # "realistic" or "paper"
    label: str
    argv: tuple[str, ...]

    @property
    def key(self) -> str:
        return re.sub(r"[^a-z0-9]+", "-", self.label.lower()).strip("-")


ROWS: tuple[Row, ...] = (
    Row("realistic", "Pacific, the paper's epoch (2024.36), WMM2020 as the map, INS heading",
        ("--scenario", "pacific", "--controllers", "fc")),
    Row("realistic", "Pacific 2025, WMM2025 as the map, INS heading",
        ("--scenario", "pacific_2025", "--controllers", "fc")),
    Row("realistic", "Pacific 2025, WMMHR-2025 as the map, INS heading",
        ("--scenario", "pacific_2025", "--controllers", "fc", "--param", "NAV_MAP=1")),
    Row("realistic", "Pacific 2025, WMMHR-2025, compass heading, no INS",
        ("--scenario", "pacific_2025", "--controllers", "fc", "--param", "NAV_MAP=1",
         "--heading-source", "magnetic", "--no-ins")),
    Row("realistic", "Tasman 2025 (40S 160E -> 36S 168E), WMMHR-2025, INS heading",
        ("--scenario", "tasman_2025", "--controllers", "fc", "--param", "NAV_MAP=1")),
    Row("realistic", "Tasman 2025 (40S 160E -> 36S 168E), WMMHR-2025, compass heading, no INS",
        ("--scenario", "tasman_2025", "--controllers", "fc", "--param", "NAV_MAP=1",
         "--heading-source", "magnetic", "--no-ins")),
    Row("paper", "Pacific, the paper's idealised world (Table 5)",
        ("--scenario", "paper_pacific", "--controllers", "fc")),
)

FIRST_SEED = 1000

COLUMNS = (("median (km)", "median_remaining_km", "{:.2f}"),
           ("mean (km)", "remaining_km", "{:.2f}"),
           ("p90 (km)", "p90_remaining_km", "{:.2f}"),
           ("inside own 95 % ellipse", "ellipse95_pct", "{:.0f} %"),
           ("predicted 95 % radius (km)", "pred_r95_km", "{:.1f}"),
           ("inside predicted 95 %", "pred95_pct", "{:.0f} %"),
           ("arrived", "arrived", "{:.0f}"))


def run_row(row: Row, runs: int, out: Path, root: Path) -> dict:
    """Fly one row with the ``fcmpc-montecarlo`` command of the checkout at ``root`` and return its
    Fc-MPC summary plus the p90 of its runs."""
    import csv
    import sys

    folder = (out / row.key).resolve()
    argv = [*row.argv, "--runs", str(runs), "--first-seed", str(FIRST_SEED), "--out", str(folder), "--no-plots",
            "--quiet"]
    done = subprocess.run([sys.executable, "-m", "fcmpc.montecarlo.cli", *argv], cwd=root)
    if done.returncode != 0:
        raise RuntimeError(f"fcmpc-montecarlo {' '.join(argv)} exited {done.returncode}")
    (summary_file,) = folder.glob("*/summary.json")
    summary = json.loads(summary_file.read_text())["summary"]["Fc-MPC"]
    with open(summary_file.with_name("runs.csv"), newline="") as handle:
        miss = sorted(float(r["remaining_km"]) for r in csv.DictReader(handle) if r["controller"] == "Fc-MPC")
    summary["p90_remaining_km"] = miss[min(len(miss) - 1, math.ceil(0.9 * len(miss)) - 1)]
    return summary


def _cell(summary: dict, key: str, fmt: str) -> str:
    value = summary.get(key, math.nan)
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else fmt.format(value)


def table(rows: list[tuple[Row, dict]], runs: int) -> str:
    """The Markdown table of one group of rows (Fc-MPC, miss at rest, seeds from FIRST_SEED)."""
    head = "| world | " + " | ".join(c[0] for c in COLUMNS) + " |"
    lines = [head, "|---" * (len(COLUMNS) + 1) + "|"]
    for row, summary in rows:
        lines.append(f"| {row.label} | " + " | ".join(_cell(summary, k, f) for _, k, f in COLUMNS) + " |")
    lines.append(f"\nFc-MPC, miss at rest, seeds {FIRST_SEED}-{FIRST_SEED + runs - 1}; commands in "
                 "[docs/results.md](docs/results.md).")
    return "\n".join(lines)


def render(results: list[tuple[Row, dict]], runs: int, commit: str, when: datetime) -> str:
    """``docs/results.md``: the tables, then each row's command exactly as run."""
    parts = [
        "# Results",
        "",
        f"Generated by `fcmpc-results --runs {runs}` at commit `{commit}` on {when:%Y-%m-%d %H:%M} UTC;",
        "do not edit by hand. Each row is the `fcmpc-montecarlo` command listed below it; the README",
        "shows the same tables.",
        "",
    ]
    for name in dict.fromkeys(r.table for r, _ in results):
        group = [(r, s) for r, s in results if r.table == name]
        parts += [f"## {name}", "", table(group, runs).replace("](docs/", "]("), ""]
        parts += ["```"] + [f"fcmpc-montecarlo {' '.join(r.argv)} --runs {runs} --first-seed {FIRST_SEED}   # {r.label}"
                            for r, _ in group]
        parts += ["```", ""]
    return "\n".join(parts)


def splice_readme(readme: str, results: list[tuple[Row, dict]], runs: int) -> str:
    """The README with each ``<!-- results:NAME -->`` block replaced by that group's table."""
    for name in dict.fromkeys(r.table for r, _ in results):
        block = table([(r, s) for r, s in results if r.table == name], runs)
        pattern = re.compile(rf"<!-- results:{name} -->.*?<!-- /results:{name} -->", re.S)
        if not pattern.search(readme):
            raise ValueError(f"README has no <!-- results:{name} --> block")
        readme = pattern.sub(lambda _: f"<!-- results:{name} -->\n{block}\n<!-- /results:{name} -->", readme)
    return readme


def main(argv: list[str] | None = None) -> int:
    from companion.cli import ArgumentParser, positive_int

    parser = ArgumentParser(prog="fcmpc-results", description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=positive_int, default=50, help="seeds per row; default 50")
    parser.add_argument("--out", default="out/results", help="Monte Carlo output folder; default out/results")
    parser.add_argument("--root", default=".", help="the checkout whose docs/results.md and README.md to write")
    args = parser.parse_args(argv)
    root = Path(args.root)
    results = [(row, run_row(row, args.runs, Path(args.out), root)) for row in ROWS]
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    (root / "docs" / "results.md").write_text(render(results, args.runs, commit, datetime.now(timezone.utc)))
    readme = root / "README.md"
    readme.write_text(splice_readme(readme.read_text(), results, args.runs))
    print(render(results, args.runs, commit, datetime.now(timezone.utc)))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())

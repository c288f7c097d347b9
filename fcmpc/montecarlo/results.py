"""The published results: each row one ``fcmpc-montecarlo`` command, run and tabulated.

``fcmpc-results`` runs every row of :data:`ROWS` through the Monte Carlo's own command line (so a
published figure is exactly what that command prints), writes ``docs/results.md`` with the
commands, the commit and the date, and puts the same tables into the README between its
``<!-- results:NAME -->`` markers (a table whose block the README lacks is only written to
``docs/results.md``). ``--table NAME`` runs one table and leaves the others as they were. Nothing
here computes a figure of its own: the numbers are the ``summary.json`` each command writes, or for
the storm table the runs each command stores.

The storm table (:data:`STORM_VARIANTS`): every storm of the library (``sitl/storms/events.toml``) on
its realistic scenario, scored leave-one-storm-out (``--storm-params loo``, the default: parameters
fitted on the other storms, ``params/storms-<others>-by-miss.parm`` when fitted by miss), with the
index feed on, off, and on with zero publication delay; one ``fcmpc-montecarlo --sweep`` of one cell
each (a sweep flies the storm only, not the same seeds without it).

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
import statistics
import subprocess
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from companion.nav.metrics import percentile

__all__ = ["Row", "ROWS", "STORM_VARIANTS", "TABLES", "render", "render_storms", "run_row", "run_storm", "splice",
           "storm_table", "main"]


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
TABLES = ("realistic", "paper", "storms")

# The storm table's columns: the same storm world with the index feed as published, switched off, and as
# published with no delay and no quick-look error (the last completed interval's definitive value).
STORM_VARIANTS = (
    ("feed on", ("--sweep", "storm.kp_feed=1")),
    ("feed off", ("--sweep", "storm.kp_feed=0", "--sweep", "storm.symh_feed=0")),
    ("zero delay", tuple(a for key in ("kp_delay_s", "kp_error", "ring_delay_s", "ring_batch_s", "ring_offset_nt",
                                       "ring_error_nt") for a in ("--sweep", f"storm.{key}=0"))),
)

COLUMNS = (("median (km)", "median_remaining_km", "{:.2f}"),
           ("mean (km)", "remaining_km", "{:.2f}"),
           ("p90 (km)", "p90_remaining_km", "{:.2f}"),
           ("inside own 95 % ellipse", "ellipse95_pct", "{:.0f} %"),
           ("predicted 95 % radius (km)", "pred_r95_km", "{:.1f}"),
           ("inside predicted 95 %", "pred95_pct", "{:.0f} %"),
           ("arrived", "arrived", "{:.0f}"))


def _montecarlo(argv: tuple[str, ...], runs: int, folder: Path, root: Path) -> None:
    """Run ``fcmpc-montecarlo`` of the checkout at ``root`` on seeds FIRST_SEED.. into ``folder``."""
    import sys

    argv = (*argv, "--runs", str(runs), "--first-seed", str(FIRST_SEED), "--out", str(folder), "--no-plots", "--quiet")
    done = subprocess.run([sys.executable, "-m", "fcmpc.montecarlo.cli", *argv], cwd=root)
    if done.returncode != 0:
        raise RuntimeError(f"fcmpc-montecarlo {' '.join(argv)} exited {done.returncode}")


def run_row(row: Row, runs: int, out: Path, root: Path) -> dict:
    """Fly one row with the ``fcmpc-montecarlo`` command of the checkout at ``root`` and return its
    Fc-MPC summary plus the p90 of its runs."""
    import csv

    folder = (out / row.key).resolve()
    _montecarlo(row.argv, runs, folder, root)
    (summary_file,) = folder.glob("*/summary.json")
    summary = json.loads(summary_file.read_text())["summary"]["Fc-MPC"]
    with open(summary_file.with_name("runs.csv"), newline="") as handle:
        miss = [float(r["remaining_km"]) for r in csv.DictReader(handle) if r["controller"] == "Fc-MPC"]
    summary["p90_remaining_km"] = percentile(miss, 0.9)
    return summary


def storm_argv(event: str, variant: tuple[str, ...]) -> tuple[str, ...]:
    """The ``fcmpc-montecarlo`` arguments of one storm cell (Fc-MPC, leave-one-storm-out by default)."""
    return ("--scenario", f"{event}_real", "--controllers", "fc", *variant)


def run_storm(event: str, variant: tuple[str, ...], runs: int, out: Path, root: Path) -> dict:
    """Fly one storm cell (a one-cell ``--sweep``) and summarise its stored runs: median, p90, share
    inside the own 95 % ellipse, runs; the training storms and ``FUS_SYMH_K``/``FUS_BQA_N`` flown."""
    from fcmpc.montecarlo.store import RunStore

    folder = (out / "storms" / f"{event}-{re.sub(r'[^a-z0-9]+', '-', ' '.join(variant[1::2]))}").resolve()
    _montecarlo(storm_argv(event, variant), runs, folder, root)
    sweep = folder / f"{event}_real" / "sweep"
    stored = json.loads((sweep / "summary.json").read_text())
    # only this sweep's runs: the store keeps older ones (other code, other parameters) beside them
    rows = [r for r in RunStore(sweep / "runs").read(set(stored["run_keys"])).to_pylist()
            if r["controller"] == "Fc-MPC" and FIRST_SEED <= r["seed"] < FIRST_SEED + runs]
    miss = [float(r["remaining_km"]) for r in rows]
    inside = [float(r["in_ellipse95"]) for r in rows if r["in_ellipse95"] is not None]
    fitted = stored.get("storm_params") or {}
    r95_km = storm_prediction_r95_km(event, rows[0])
    return {"median_km": statistics.median(miss), "p90_km": percentile(miss, 0.9), "inside_pct": 100.0 * sum(inside) / len(inside) if inside else math.nan,
            "pred_r95_km": r95_km, "pred95_pct": 100.0 * sum(m <= r95_km for m in miss) / len(miss),
            "runs": len(miss), "storms": fitted.get("storms") or [],
            "symh_k": rows[0]["FUS_SYMH_K"], "bqa_n": rows[0]["FUS_BQA_N"]}


def storm_prediction_r95_km(event: str, row: dict) -> float:
    """The 95 % radius at arrival that the vehicle of storm ``event``'s world is told before flying
    (:func:`fcmpc.montecarlo.cli_table.route_prediction`, as every other table's row) with the navigator's
    settings of a stored run ``row``: it knows the route, its sensors and its settings, not the storm."""
    from companion.registry import SPEC_BY_NAME
    from fcmpc.montecarlo.cli_table import route_prediction
    from sitl.scenario import load_scenario

    values = {name: value for name, value in row.items() if name in SPEC_BY_NAME and name != "NAV_CONTROLLER"}
    return route_prediction(load_scenario(f"{event}_real"), values).arrival_r95_m / 1e3


STORM_HEAD = ("storm", "fitted on (FUS_BQA_N, FUS_SYMH_K)", "feed on: median (km)", "p90 (km)", "inside own 95 %",
              "inside predicted 95 %", "feed off: median (km)", "p90 (km)", "inside own 95 %", "on vs off", "zero delay: median (km)", "runs")


def storm_table(results: list[tuple[str, dict[str, dict]]], runs: int) -> str:
    """The storm table: a row per storm, its feed on / off / zero-delay cells (:func:`run_storm`)."""
    lines = ["| " + " | ".join(STORM_HEAD) + " |", "|---" * len(STORM_HEAD) + "|"]
    for label, cells in results:
        on, off, zero = (cells.get(name, {}) for name, _ in STORM_VARIANTS)
        ratio = on["median_km"] / off["median_km"] - 1.0 if on and off else math.nan
        fitted = f"{', '.join(on.get('storms', []))} ({on.get('bqa_n', math.nan):g}, {on.get('symh_k', math.nan):g})"
        values = [label, fitted,
                  *(_cell(on, k, f) for k, f in (("median_km", "{:.2f}"), ("p90_km", "{:.2f}"), ("inside_pct", "{:.0f} %"),
                                                 ("pred95_pct", "{:.0f} %"))),
                  *(_cell(off, k, f) for k, f in (("median_km", "{:.2f}"), ("p90_km", "{:.2f}"),
                                                  ("inside_pct", "{:.0f} %"))),
                  f"{ratio:+.0%}" if math.isfinite(ratio) else "-", _cell(zero, "median_km", "{:.2f}"),
                  "/".join(str(c.get("runs", "-")) for c in (on, off, zero))]
        lines.append("| " + " | ".join(values) + " |")
    lines.append(f"\nFc-MPC, miss at rest, seeds {FIRST_SEED}-{FIRST_SEED + runs - 1}, each storm scored with "
                 "parameters fitted without it; indices as published unless \"zero delay\"; inside predicted 95 %: "
                 "within the radius the vehicle is told before flying (it knows the route and its settings, not the "
                 "storm); runs: feed on / off / zero delay; commands in [docs/results.md](docs/results.md).")
    return "\n".join(lines)


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


def section(name: str, body: str, runs: int, commit: str, when: datetime, options: str = "") -> str:
    """One table's block of ``docs/results.md``: when and at which commit, the table, the commands."""
    return "\n".join([f"<!-- results:{name} -->", f"## {name}", "",
                      f"Generated by `fcmpc-results --table {name} --runs {runs}{options}` at commit `{commit}` on "
                      f"{when:%Y-%m-%d %H:%M} UTC.", "", body, f"<!-- /results:{name} -->"])


def render(results: list[tuple[Row, dict]], runs: int, commit: str, when: datetime) -> dict[str, str]:
    """The ``docs/results.md`` block of each table of ``results`` (Rows): the table, each row's command."""
    blocks = {}
    for name in dict.fromkeys(r.table for r, _ in results):
        group = [(r, s) for r, s in results if r.table == name]
        body = [table(group, runs).replace("](docs/", "]("), "", "```"]
        body += [f"fcmpc-montecarlo {' '.join(r.argv)} --runs {runs} --first-seed {FIRST_SEED}   # {r.label}"
                 for r, _ in group]
        blocks[name] = section(name, "\n".join(body + ["```", ""]), runs, commit, when)
    return blocks


def render_storms(results: list[tuple[str, dict[str, dict]]], events: list[str], flown, runs: int, commit: str,
                  when: datetime) -> str:
    """The storm table's ``docs/results.md`` block, with the commands of the cells ``flown``."""
    body = [storm_table(results, runs).replace("](docs/", "]("), "", "```"]
    body += [f"fcmpc-montecarlo {' '.join(storm_argv(event, variant))} --runs {runs} --first-seed {FIRST_SEED}"
             f"   # {name}" for event in events for name, variant in flown]
    cells = "" if len(flown) == len(STORM_VARIANTS) else f" --storm-cells '{','.join(n for n, _ in flown)}'"
    return section("storms", "\n".join(body + ["```", ""]), runs, commit, when, cells)


RESULTS_HEAD = """# Results

Generated by `fcmpc-results` (`--table NAME` regenerates one table); do not edit by hand. Each row is
the `fcmpc-montecarlo` command listed below its table; the README shows the same tables.
"""


def splice(text: str, blocks: dict[str, str], required: bool = True) -> str:
    """``text`` with each ``<!-- results:NAME -->`` block replaced by ``blocks[NAME]`` (which holds
    its own markers); a block ``text`` lacks raises ValueError when ``required``, else is appended."""
    for name, block in blocks.items():
        pattern = re.compile(rf"<!-- results:{name} -->.*?<!-- /results:{name} -->", re.S)
        if pattern.search(text):
            text = pattern.sub(lambda _: block, text)
        elif required:
            raise ValueError(f"no <!-- results:{name} --> block")
        else:
            text = text.rstrip("\n") + "\n\n" + block + "\n"
    return text


def readme_blocks(tables: dict[str, str]) -> dict[str, str]:
    """The README's blocks: each table between its markers."""
    return {name: f"<!-- results:{name} -->\n{body}\n<!-- /results:{name} -->" for name, body in tables.items()}


def main(argv: list[str] | None = None) -> int:
    from companion.cli import ArgumentParser, positive_int
    from sitl.storms.events import storm_events

    parser = ArgumentParser(prog="fcmpc-results", description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=positive_int, default=50, help="seeds per row; default 50")
    parser.add_argument("--out", default="out/results", help="Monte Carlo output folder; default out/results")
    parser.add_argument("--root", default=".", help="the checkout whose docs/results.md and README.md to write")
    parser.add_argument("--table", action="append", choices=TABLES, default=None,
                        help="run this table only (repeatable); default all; the others stay as they are")
    parser.add_argument("--storm-cells", default=",".join(n for n, _ in STORM_VARIANTS), metavar="NAMES",
                        help="the storm table's cells to fly (comma list of " + ", ".join(n for n, _ in STORM_VARIANTS)
                             + "); default all; a cell not flown shows '-'")
    args = parser.parse_args(argv)
    root, out = Path(args.root), Path(args.out)
    flown = [v for v in STORM_VARIANTS if v[0] in {n.strip() for n in args.storm_cells.split(",")}]
    wanted = tuple(args.table or TABLES)
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    when = datetime.now(timezone.utc)
    results = [(row, run_row(row, args.runs, out, root)) for row in ROWS if row.table in wanted]
    docs = render(results, args.runs, commit, when)
    readme = {name: table([(r, s) for r, s in results if r.table == name], args.runs) for name in docs}
    if "storms" in wanted:
        events = [event.name for event in storm_events()]
        titles = {event.name: event.title for event in storm_events()}
        cells = {(e, name): run_storm(e, variant, args.runs, out, root)   # every storm's feed on first
                 for name, variant in flown for e in events}
        storms = [(f"{titles[e]} (`{e}_real`)", {name: cells[e, name] for name, _ in flown}) for e in events]
        docs["storms"] = render_storms(storms, events, flown, args.runs, commit, when)
        readme["storms"] = storm_table(storms, args.runs)
    path = root / "docs" / "results.md"
    old = path.read_text() if path.exists() else RESULTS_HEAD
    path.write_text(splice(RESULTS_HEAD + old[old.index("<!-- results:"):] if "<!-- results:" in old else RESULTS_HEAD,
                           docs, required=False))
    readme_path = root / "README.md"
    text = readme_path.read_text()
    present = {n: b for n, b in readme_blocks(readme).items() if f"<!-- results:{n} -->" in text}
    readme_path.write_text(splice(text, present))
    for name in sorted(set(readme) - set(present)):
        print(f"README.md has no <!-- results:{name} --> block: the table is in {path} only")
    print("\n\n".join(docs.values()))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())

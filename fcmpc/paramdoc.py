"""The parameter reference, generated from the registry (:mod:`companion.registry`).

Three files, each a view of :data:`~companion.registry.REGISTRY` and nothing else:

* ``params/defaults.parm``: every parameter at its default, each preceded by ``#`` comments
  with its description, range and unit (ArduPilot ``.parm``: MAVProxy's ``param load``, the
  companion's ``--params`` and Mission Planner skip ``#`` lines),
* ``docs/parameters.md``: the reference for people, grouped, with name, description, unit,
  range, default and when a change takes effect,
* ``docs/parameters.json``: the same in the MAVLink component-metadata parameter format that
  QGroundControl reads (``COMP_METADATA_TYPE_PARAMETER``), ready to be served once the MAVLink
  library carries the component-metadata messages.

``fcmpc-params --write`` (or ``python scripts/params_doc.py --write``) regenerates them;
``fcmpc-params --check`` exits 1 naming the stale ones (tests/test_paramdoc.py runs it).

>>> when_applied(SPEC_BY_NAME["NAV_DEST_LAT"]), when_applied(SPEC_BY_NAME["SAFE_TMO_S"])
('next mission', 'start-up only')
"""
from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from companion.cli import ArgumentParser, run_main
from companion.params import format_value, write_text_atomically
from companion.registry import REGISTRY, SPEC_BY_NAME, ParamSpec

__all__ = ["APPLIES", "GENERATED", "GROUPS", "group_of", "when_applied", "parm_text", "markdown_text", "metadata_json",
           "stale_files", "write_files", "main"]

# the groups, by name prefix (QGroundControl groups an unknown component's parameters the same
# way, by the text before the first '_'), in the order the reference lists them
GROUPS: tuple[tuple[str, str, str], ...] = (
    ("NAV_", "Mission", "where the vehicle goes, how fast, when it has arrived, what it navigates on "
                        "(the paper's Table 4, \"Mission Settings\")"),
    ("GRAD_", "Gradient estimation", "how the field's gradient G is learned from the vehicle's moves (eq. 5-12)"),
    ("MPC_", "Model predictive control", "the controller's weights, horizon and bounds (eq. 13-38, Table 4)"),
    ("FUS_", "Estimation", "the position estimator: Table 3's fusion and the error-state filter, its noise, "
                           "bias, storm and INS models (eq. 46-58)"),
    ("COMP_", "Companion process", "the link to the flight controller, the setpoint stream, the position fed "
                                   "back and the failsafe timeouts"),
    ("SAFE_", "Safety ceiling", "limits set in the .parm file at start that no PARAM_SET can raise"),
    ("LINK_", "Link", "who may write parameters, and the link's records"),
    ("MAG_", "Magnetometer calibration", "hard- and soft-iron correction applied to every sample"),
)

APPLIES = {
    "at once": "a PARAM_SET applies at the next control step, in flight too",
    "next mission": "a PARAM_SET in flight is stored and applies to the next mission (the running one "
                    "keeps its value; the companion says so in a STATUSTEXT)",
    "start-up only": "read from the .parm file at start; every PARAM_SET is refused",
    "reading": "a measurement the ground station renews over the link; it counts only while fresh, "
               "and is never written to the .parm file",
}


def group_of(spec: ParamSpec) -> str:
    """The title of the parameter's group."""
    for prefix, title, _ in GROUPS:
        if spec.name.startswith(prefix):
            return title
    raise ValueError(f"{spec.name}: no group for its prefix (add one to fcmpc.paramdoc.GROUPS)")


def when_applied(spec: ParamSpec) -> str:
    """When a change of the parameter takes effect: a key of :data:`APPLIES`."""
    if spec.boot_only:
        return "start-up only"
    if spec.max_age_s is not None:
        return "reading"
    return "next mission" if spec.frozen else "at once"


def _grouped() -> list[tuple[tuple[str, str, str], list[ParamSpec]]]:
    return [(group, [spec for spec in REGISTRY if group_of(spec) == group[1]]) for group in GROUPS]


def _number(value: float) -> str:
    """A bound or default for people: whole numbers without a decimal point or exponent."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e9 else format_value(float(value))


def _range(spec: ParamSpec) -> str:
    return f"{_number(spec.minimum)} .. {_number(spec.maximum)}"


def parm_text() -> str:
    """Every parameter at its default as ``.parm`` text, grouped, each preceded by its
    description, range, unit and (where not at once) when a change applies."""
    lines = ["# fcmpc companion parameters (MAVLink component 191) at their defaults.",
             "# Generated from companion/registry.py by `fcmpc-params --write`: do not edit here.",
             "# NAME VALUE per line (ArduPilot .parm); load with --params, MAVProxy's `param load`",
             "# or Mission Planner. The reference with every detail: docs/parameters.md."]
    for (_, title, about), specs in _grouped():
        lines += ["#", f"# --- {title}: {about} ---"]
        for spec in specs:
            unit = f" {spec.unit}" if spec.unit else ""
            applies = when_applied(spec)
            note = " (a change in flight applies to the next mission)" if applies == "next mission" else ""
            lines.append(f"# {spec.doc} [{_range(spec)}]{unit}{note}")
            lines.append(f"{spec.name} {format_value(spec.kind(spec.default))}")
    return "\n".join(lines) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


_MD_HEAD = """\
# Parameters of the fcmpc companion

<!-- Generated from companion/registry.py by `fcmpc-params --write`: do not edit here. -->

The companion is MAVLink component 191 on the vehicle's system id. A ground station lists its
{count} parameters beside the flight controller's (QGroundControl: *Vehicle Setup > Parameters*,
category *Component 191*; MAVProxy started with `--target-component 191`: `param fetch`, then
`param show NAV_*`). A PARAM_SET outside a parameter's range is refused: the companion answers
with the value it kept and a STATUSTEXT naming the range. It writes every accepted setting to its
`.parm` file at once, so a restart keeps it.

Files:

- `params/defaults.parm`: every parameter at its default, each preceded by its description,
  range and unit as `#` comments. MAVProxy's `param load` (which strips what follows `#`), Mission
  Planner's parameter-file reader (which skips lines starting with `#`) and the companion's own
  `--params FILE` read it. QGroundControl's *Load from file*
  reads only its own tab-separated format (`SYSID COMPID NAME VALUE TYPE`); save the list from
  QGroundControl once and edit that file instead.
- `docs/parameters.json`: the same metadata in the MAVLink component-metadata parameter format
  (`COMP_METADATA_TYPE_PARAMETER`) that QGroundControl reads. pymavlink 2.4.50, the MAVLink
  library the companion uses, has no COMPONENT_METADATA (397) or COMPONENT_INFORMATION (395)
  message and no COMP_METADATA_TYPE enum in any of its dialects (common, ardupilotmega,
  development, all), so the companion cannot announce the file and QGroundControl cannot fetch
  it over MAVLink FTP; with a pymavlink that has them, serving this file is all that is left to
  do. It declares `"version": 1`, the only version QGroundControl accepts (`CompInfoParam::setJson`),
  while MAVLink's `parameter.schema.json` now asks for 3; every other rule of that schema holds.

Regenerate all three with `fcmpc-params --write` (or `python scripts/params_doc.py --write`);
`fcmpc-params --check` fails, naming the files, when one is stale (a test runs it).

When a change takes effect (column *Changes*):

{applies}

"""


def markdown_text() -> str:
    """The parameter reference for people (``docs/parameters.md``)."""
    applies = "\n".join(f"- **{key}**: {text}." for key, text in APPLIES.items())
    parts = [_MD_HEAD.format(count=len(REGISTRY), applies=applies)]
    parts.append("Groups: " + ", ".join(f"[{title}](#{title.lower().replace(' ', '-')})"
                                        for (_, title, _), _ in _grouped()) + ".\n")
    for (prefix, title, about), specs in _grouped():
        parts.append(f"\n## {title}\n\n`{prefix}*`: {about}.\n\n"
                     "| Name | Description | Unit | Range | Default | Changes |\n"
                     "|---|---|---|---|---|---|\n")
        parts.append("".join(f"| `{spec.name}` | {_cell(spec.doc)} | {_cell(spec.unit)} | {_range(spec)} | "
                             f"{_number(spec.default)} | {when_applied(spec)} |\n" for spec in specs))
    return "".join(parts)


def _short(doc: str) -> str:
    """The description's first clause (QGroundControl shows it in the list; the whole in the editor)."""
    cut = min((i for i in (doc.find("; "), doc.find(": ")) if i >= 12), default=-1)
    return doc if cut < 0 else doc[:cut]


def metadata_json() -> str:
    """The registry in the MAVLink component-metadata parameter format (``docs/parameters.json``)."""
    parameters = []
    for spec in REGISTRY:
        applies = when_applied(spec)
        entry: dict[str, object] = {
            "name": spec.name,
            "type": "Int32" if spec.kind is int else "Float",
            "shortDesc": _short(spec.doc),
            "longDesc": f"{spec.doc}. Changes: {applies} ({APPLIES[applies]}).",
            "units": spec.unit,
            "default": spec.kind(spec.default),
            "min": spec.kind(spec.minimum),
            "max": spec.kind(spec.maximum),
            "group": group_of(spec),
        }
        if applies == "start-up only":
            entry["rebootRequired"] = True      # the companion reads it only at start
        if applies == "reading":
            entry["volatile"] = True            # renewed over the link; not a setting
        parameters.append(entry)
    return json.dumps({"version": 1, "parameters": parameters}, indent=2) + "\n"


# what is generated, relative to the repository's root
GENERATED: dict[str, Callable[[], str]] = {
    "params/defaults.parm": parm_text,
    "docs/parameters.md": markdown_text,
    "docs/parameters.json": metadata_json,
}


def stale_files(root: Path) -> list[str]:
    """The generated files under ``root`` that differ from what the registry gives now."""
    stale = []
    for relative, make in GENERATED.items():
        path = root / relative
        if not path.is_file() or path.read_text(encoding="utf-8") != make():
            stale.append(relative)
    return stale


def write_files(root: Path) -> list[str]:
    """Write every generated file that changed (atomically); returns those written."""
    written = []
    for relative in stale_files(root):
        write_text_atomically(root / relative, GENERATED[relative]())
        written.append(relative)
    return written


def _default_root() -> Path:
    return Path(__file__).resolve().parents[1]


def main(argv: Sequence[str] | None = None) -> int:
    parser = ArgumentParser(
        prog="fcmpc-params",
        description="The parameter reference generated from companion/registry.py: "
                    + ", ".join(GENERATED) + ". Without an option: print the Markdown.")
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", action="store_true", help="rewrite the files that are stale")
    action.add_argument("--check", action="store_true", help="exit 1 naming the files that are stale")
    parser.add_argument("--root", type=Path, default=None,
                        help="the repository's root (default: the one this package is in)")
    args = parser.parse_args(argv)
    root = args.root if args.root is not None else _default_root()

    def run() -> int:
        if args.write:
            written = write_files(root)
            print("written: " + ", ".join(written) if written else "up to date")
            return 0
        if args.check:
            stale = stale_files(root)
            if stale:
                print("stale (run fcmpc-params --write): " + ", ".join(stale), file=sys.stderr)
                return 1
            return 0
        sys.stdout.write(markdown_text())
        return 0

    return run_main("fcmpc-params", run)

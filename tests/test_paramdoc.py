"""The generated parameter reference (fcmpc.paramdoc): the committed files are what the
registry gives now, and each is read by the program it is for.

The MAVLink schema in tests/data/mavlink/parameter.schema.json is mavlink/mavlink's
component_metadata/parameter.schema.json at commit 057c744a4e3d04f5f3f1e4ac5a94ac0017e2eb3b.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
from pymavlink import mavparm

from fcmpc.paramdoc import GENERATED, main, stale_files, when_applied, write_files
from companion.params import default_values, read_parm_file
from companion.registry import REGISTRY

REPO = Path(__file__).resolve().parents[1]
SCHEMA = Path(__file__).resolve().parent / "data" / "mavlink" / "parameter.schema.json"


def test_committed_files_are_what_the_registry_gives(tmp_path):
    assert write_files(tmp_path) == list(GENERATED)          # regenerated from nothing, in a temp dir
    for relative in GENERATED:
        assert (REPO / relative).read_text(encoding="utf-8") == (tmp_path / relative).read_text(encoding="utf-8"), \
            f"{relative} is stale: run fcmpc-params --write"
    assert stale_files(REPO) == []


def test_check_names_a_stale_file_and_write_mends_it(tmp_path, capsys):
    write_files(tmp_path)
    path = tmp_path / "docs" / "parameters.md"
    path.write_text(path.read_text().replace("| 0 .. 5 |", "| 0 .. 6 |"))
    assert main(["--check", "--root", str(tmp_path)]) == 1
    assert "docs/parameters.md" in capsys.readouterr().err
    assert main(["--write", "--root", str(tmp_path)]) == 0 and stale_files(tmp_path) == []


def test_the_script_runs_as_a_file():
    done = subprocess.run([sys.executable, str(REPO / "scripts" / "params_doc.py"), "--check"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_defaults_parm_reads_back_in_the_companion_and_in_mavproxy(tmp_path):
    path = REPO / "params" / "defaults.parm"
    assert read_parm_file(path) == default_values()
    loaded = mavparm.MAVParmDict()          # what MAVProxy's `param load` uses (no vehicle: values only)
    assert loaded.load(str(path))
    assert {name: value for name, value in loaded.items()} == {k: float(v) for k, v in default_values().items()}
    text = path.read_text()
    for spec in REGISTRY:                   # each value line follows its description, range and unit
        comment = text.split(f"\n{spec.name} ", 1)[0].rsplit("\n", 1)[1]
        assert comment.startswith(f"# {spec.doc} [") and comment.split("]", 1)[1].startswith(
            f" {spec.unit}" if spec.unit else ""), spec.name


def test_metadata_json_is_the_mavlink_format_qgroundcontrol_reads():
    document = json.loads((REPO / "docs" / "parameters.json").read_text())
    assert document["version"] == 1         # QGroundControl's CompInfoParam::setJson accepts only 1
    # every other rule of MAVLink's schema (which now asks for version >= 3)
    jsonschema.validate(dict(document, version=3), json.loads(SCHEMA.read_text()))
    by_name = {entry["name"]: entry for entry in document["parameters"]}
    assert list(by_name) == [spec.name for spec in REGISTRY]
    for spec in REGISTRY:
        entry = by_name[spec.name]
        assert entry["type"] == ("Int32" if spec.kind is int else "Float")
        assert (entry["min"], entry["max"], entry["default"]) == (spec.minimum, spec.maximum, spec.default)
        assert entry["units"] == spec.unit and entry["longDesc"].startswith(spec.doc)
        assert entry.get("rebootRequired", False) == spec.boot_only
        assert entry.get("volatile", False) == (spec.max_age_s is not None)


def test_markdown_has_one_row_per_parameter_with_its_range_and_when_it_applies():
    text = (REPO / "docs" / "parameters.md").read_text()
    found = [(m.group(1), m.group(0)) for m in re.finditer(r"^\| `([A-Z0-9_]+)` \|.*\|$", text, re.M)]
    rows = dict(found)
    assert len(found) == len(rows) and sorted(rows) == sorted(spec.name for spec in REGISTRY)
    for spec in REGISTRY:
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", rows[spec.name])[1:-1]]
        assert cells[2] == spec.unit and cells[5] == when_applied(spec), spec.name
        low, high = (float(x) for x in cells[3].split(" .. "))
        assert (low, high, float(cells[4])) == (spec.minimum, spec.maximum, spec.default), spec.name
    assert "COMPONENT_METADATA" in text     # why QGroundControl cannot fetch the JSON over MAVLink yet


def test_a_mission_setting_applies_next_mission_and_a_weight_at_once():
    from companion.registry import SPEC_BY_NAME

    assert when_applied(SPEC_BY_NAME["NAV_DEST_LAT"]) == "next mission"   # Mission.reconfigure keeps it
    assert when_applied(SPEC_BY_NAME["MPC_R_X"]) == "at once"
    assert when_applied(SPEC_BY_NAME["SAFE_SPEED_KMH"]) == "start-up only"
    assert when_applied(SPEC_BY_NAME["NAV_KP"]) == "reading"

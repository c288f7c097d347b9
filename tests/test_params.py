"""The parameter registry, .parm files and the configs derived from them (companion.params)."""
from __future__ import annotations

import math
import os
import re
from dataclasses import fields
from pathlib import Path

import pytest

from companion import params
from companion.params import (
    READINGS,
    REGISTRY,
    SPEC_BY_NAME,
    CompanionConfig,
    NavConfig,
    ParamError,
    default_values,
    read_parm_file,
    validate,
    validate_all,
    write_parm_file,
)
from sitl.scenario import SCENARIO_DIR, load_scenario


# --- registry ------------------------------------------------------------------------------------
def test_every_registry_entry_is_well_formed():
    names = [spec.name for spec in REGISTRY]
    assert len(names) == len(set(names)), "duplicate parameter names"
    for spec in REGISTRY:
        assert len(spec.name) <= 16, spec.name  # MAVLink param_id is char[16]
        assert spec.name == spec.name.upper() and spec.name.isascii()
        assert spec.kind in (int, float), spec.name
        assert spec.minimum <= spec.default <= spec.maximum, spec.name
        if spec.kind is int:
            assert float(spec.default).is_integer() and float(spec.minimum).is_integer(), spec.name
        assert spec.doc, spec.name
    assert set(SPEC_BY_NAME) == set(names)


def test_defaults_are_the_papers_table_4():
    v = default_values()
    assert (v["NAV_START_LAT"], v["NAV_START_LON"], v["NAV_DEST_LAT"], v["NAV_DEST_LON"]) == (33.0, 152.0, 28.0, 158.0)
    assert v["MPC_HORIZON"] == 2 and isinstance(v["MPC_HORIZON"], int)
    assert (v["MPC_Q_D"], v["MPC_Q_I"], v["MPC_F_D"], v["MPC_F_I"]) == (1.0, 1.0, 1.0, 1.0)
    assert (v["MPC_R_X"], v["MPC_R_Y"]) == (10.0, 10.0)
    assert (v["MPC_S_MIN_D"], v["MPC_S_MIN_I"], v["MPC_S_MAX_D"], v["MPC_S_MAX_I"]) == (-10.0, 10.0, 100.0, 100.0)
    assert v["MPC_U_MAX_KMH"] == 40.0 and v["NAV_SPEED_KMH"] == 50.0
    assert (v["NAV_PROBE1_DEG"], v["NAV_PROBE2_DEG"]) == (0.0, 270.0)


# --- validation ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name,value,match", [
    ("NAV_BOGUS", 1.0, "unknown parameter 'NAV_BOGUS'"),
    ("NAV_SPEED_KMH", 500.0, r"NAV_SPEED_KMH: 500.0 is out of range \[1, 300\] km/h"),
    ("MPC_HORIZON", 2.5, "MPC_HORIZON: 2.5 is not an integer"),
    ("MPC_HORIZON", 0, r"MPC_HORIZON: 0 is out of range \[1, 20\]"),
    ("NAV_ARRIVE_M", "abc", "NAV_ARRIVE_M: 'abc' is not a number"),
    ("NAV_ARRIVE_M", math.nan, "NAV_ARRIVE_M: nan is not finite"),
    ("NAV_ARRIVE_M", "inf", "NAV_ARRIVE_M: 'inf' is not finite"),
])
def test_validate_refuses_with_a_message_naming_the_parameter(name, value, match):
    with pytest.raises(ParamError, match=match):
        validate(name, value)


def test_validate_coerces_types_and_accepts_lower_case_names():
    assert validate("mpc_horizon", "3") == 3 and isinstance(validate("MPC_HORIZON", 3.0), int)
    assert isinstance(validate("NAV_SPEED_KMH", 60), float)
    merged = validate_all({"nav_speed_kmh": 72})
    assert merged["NAV_SPEED_KMH"] == 72.0 and "nav_speed_kmh" not in merged
    assert set(merged) == set(SPEC_BY_NAME)


# --- .parm files ---------------------------------------------------------------------------------
AWKWARD = {
    "NAV_SPEED_KMH": 1.0 / 3.0 * 100.0,   # not a short decimal
    "NAV_YEAR": 2024.36,
    "FUS_RC_KM2": 1e-9,                   # the minimum, in exponent notation
    "NAV_LOOKAHEAD_M": 1e6,
    "MPC_S_MIN_D": -10.0,
    "MPC_HORIZON": 7,
    "NAV_CONTROLLER": 0,
    "NAV_MAX_STEPS": 100000,
    "MAG_OFS_X": -2999.999999999,
}


def test_parm_file_round_trips_ints_and_floats_exactly(tmp_path):
    path = tmp_path / "nav.parm"
    write_parm_file(path, AWKWARD, header="written by a test\nsecond line")
    back = read_parm_file(path)
    assert back == AWKWARD
    for name, value in back.items():
        assert type(value) is SPEC_BY_NAME[name].kind, name
    text = path.read_text()
    assert text.startswith("# written by a test\n# second line\n")
    # the whole registry, at its defaults, round-trips too
    write_parm_file(path, default_values())
    assert read_parm_file(path) == default_values()


def test_parm_reader_accepts_ardupilot_syntax(tmp_path):
    path = tmp_path / "mp.parm"
    path.write_text("# Mission Planner export\n\nNAV_SPEED_KMH,45.5\nMPC_HORIZON\t3   # trailing comment\n"
                    "  nav_arrive_m 800\n")
    assert read_parm_file(path) == {"NAV_SPEED_KMH": 45.5, "MPC_HORIZON": 3, "NAV_ARRIVE_M": 800.0}


@pytest.mark.parametrize("line,words", [
    ("NAV_BOGUS 1", ["unknown parameter", "NAV_BOGUS"]),
    ("NAV_SPEED_KMH 500", ["NAV_SPEED_KMH", "out of range", "[1, 300]"]),
    ("MPC_HORIZON 2.5", ["MPC_HORIZON", "not an integer"]),
    ("NAV_ARRIVE_M twelve", ["NAV_ARRIVE_M", "not a number"]),
    ("NAV_ARRIVE_M 1 2", ["expected 'NAME VALUE'"]),
    ("NAV_ARRIVE_M", ["expected 'NAME VALUE'"]),
])
def test_bad_parm_line_is_reported_with_file_line_and_parameter(tmp_path, line, words):
    path = tmp_path / "bad.parm"
    path.write_text(f"# header\nNAV_ARRIVE_M 700\n\n{line}\nMPC_HORIZON 3\n")
    with pytest.raises(ParamError) as info:
        read_parm_file(path)
    message = str(info.value)
    assert f"{path}:4:" in message
    for word in words:
        assert word in message


def test_atomic_write_leaves_no_temporary_files(tmp_path):
    path = tmp_path / "sub" / "nav.parm"
    write_parm_file(path, {"MPC_HORIZON": 3})
    write_parm_file(path, {"MPC_HORIZON": 4})
    assert sorted(p.name for p in path.parent.iterdir()) == ["nav.parm"]
    assert read_parm_file(path) == {"MPC_HORIZON": 4}


@pytest.mark.parametrize("fail_in", ["replace", "fsync"])
def test_failed_write_keeps_the_old_file_intact(tmp_path, monkeypatch, fail_in):
    path = tmp_path / "nav.parm"
    write_parm_file(path, AWKWARD)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk on fire")

    monkeypatch.setattr(params.os, fail_in, boom)
    with pytest.raises(OSError, match="disk on fire"):
        write_parm_file(path, {"MPC_HORIZON": 9, "NAV_SPEED_KMH": 99.0})
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert read_parm_file(path) == AWKWARD
    assert [p.name for p in tmp_path.iterdir()] == ["nav.parm"]


# --- derived configs -------------------------------------------------------------------------------
def _params_of(cls) -> list[str]:
    """The registry names behind a settings class's fields, nested settings included."""
    names: list[str] = []
    for f in fields(cls):
        names += [f.metadata["param"]] if "param" in f.metadata else _params_of(f.default_factory)
    return names


def test_navconfig_defaults_match_the_registry_and_converts_units():
    assert NavConfig.from_values(default_values()) == NavConfig()
    values = validate_all({"NAV_SPEED_KMH": 72.0, "MPC_U_MAX_KMH": 36.0, "FUS_QC_KM2": 0.5, "FUS_RC_KM2": 3.0,
                           "FUS_P0_KM2": 2.0, "FUS_SIGMA": 0.004, "MPC_HORIZON": 5, "NAV_CONTROLLER": 1})
    cfg = NavConfig.from_values(values)
    assert cfg.speed_mps == pytest.approx(20.0)          # 72 km/h = 72000 m / 3600 s
    assert cfg.u_max_mps == pytest.approx(10.0)
    assert cfg.fusion.qc_m2 == pytest.approx(0.5e6)      # 1 km^2 = 1e6 m^2
    assert cfg.fusion.rc_m2 == pytest.approx(3.0e6)
    assert cfg.fusion.p0_m2 == pytest.approx(2.0e6)
    assert cfg.fusion_sigma_deg_per_m == pytest.approx(4e-6)   # 0.004 deg/km = 4e-6 deg/m
    assert cfg.horizon == 5 and isinstance(cfg.horizon, int) and cfg.controller == 1
    assert NavConfig().speed_mps == pytest.approx(50.0 / 3.6)
    assert cfg.replace(horizon=3).horizon == 3 and cfg.horizon == 5


def test_every_navigation_parameter_reaches_navconfig_exactly_once():
    """Every navigation setting is a NavConfig field, once; the readings are none (they come with
    each step's measurement: the companion's control step reads them from its parameter server)."""
    mapped = _params_of(NavConfig)
    assert len(mapped) == len(set(mapped))
    nav_params = [s.name for s in REGISTRY if s.name.split("_")[0] in ("NAV", "GRAD", "MPC", "FUS")]
    assert sorted(mapped) == sorted(set(nav_params) - set(READINGS))
    assert set(READINGS) <= set(nav_params) and not set(READINGS) & set(mapped)



def test_companionconfig_converts_units_and_collects_calibration():
    values = {**validate_all({}), "COMP_DIVERGE_KM": 12.5, "COMP_SP_RATE_HZ": 10.0, "MAG_OFS_X": 12.0,
              "MAG_OFS_Y": -3.5, "MAG_OFS_Z": 100.0, "MAG_SCALE_X": 1.1, "MAG_SCALE_Y": 0.9, "MAG_SCALE_Z": 1.0}
    cfg = CompanionConfig.from_values(values)
    assert cfg.diverge_m == pytest.approx(12500.0)
    assert cfg.setpoint_rate_hz == 10.0
    assert cfg.mag_offset_mgauss == (12.0, -3.5, 100.0)
    assert cfg.mag_scale == (1.1, 0.9, 1.0)
    assert CompanionConfig().diverge_m == pytest.approx(50e3)
    mapped = set(_params_of(CompanionConfig))
    assert mapped == {s.name for s in REGISTRY if s.name.startswith(("COMP_", "MAG_"))}
    with pytest.raises(ParamError, match="MAG_SCALE_X"):
        CompanionConfig.from_values({"MAG_SCALE_X": 9.0})


def test_parm_file_written_then_loaded_configures_the_mission(tmp_path):
    path = Path(tmp_path) / "mission.parm"
    write_parm_file(path, {"NAV_DEST_LAT": 29.5, "NAV_SPEED_KMH": 36.0, "MPC_SOLVER": 1})
    cfg = NavConfig.from_values(validate_all(read_parm_file(path)))
    assert (cfg.dest_lat_deg, cfg.speed_mps, cfg.solver) == (29.5, pytest.approx(10.0), 1)
    assert os.path.getsize(path) > 0


# ---------------------------------------------------------------------- issue 10: the start-up safety ceiling
def test_timeouts_set_over_the_link_cannot_exceed_the_start_up_ceiling():
    from companion.params import SPEC_BY_NAME

    values = {**validate_all({}), "COMP_HB_TMO_S": 60.0, "COMP_MAG_TMO_S": 2.0, "SAFE_TMO_S": 4.0}
    cfg = CompanionConfig.from_values(values)
    assert cfg.heartbeat_timeout_s == 4.0 and cfg.mag_timeout_s == 2.0
    boot_only = {s.name for s in REGISTRY if s.boot_only}
    assert boot_only == {"SAFE_SPEED_KMH", "SAFE_TMO_S", "SAFE_FENCE_KM", "LINK_GCS_ID1", "LINK_GCS_ID2"}
    assert "start-up only" in SPEC_BY_NAME["SAFE_SPEED_KMH"].doc


def test_safety_ceiling_from_the_start_up_values():
    from companion.ceiling import SafetyCeiling, distance_to_route_m

    values = {**validate_all({}), "SAFE_SPEED_KMH": 36.0, "LINK_GCS_ID2": 245, "SAFE_FENCE_KM": 50.0}
    ceiling = SafetyCeiling.from_values(values)
    assert ceiling.speed_mps == pytest.approx(10.0) and ceiling.gcs_sysids == frozenset({255, 245})
    assert ceiling.refusal("NAV_SPEED_KMH", 40.0, values) == "> SAFE_SPEED_KMH 36"
    assert ceiling.refusal("NAV_SPEED_KMH", 36.0, values) is None
    assert ceiling.refusal("NAV_DEST_LON", 158.5, values) is None                     # 49 km east of the end
    assert ceiling.refusal("NAV_DEST_LON", 159.0, values) == "outside SAFE_FENCE_KM 50"   # 98 km
    mid = distance_to_route_m(30.5, 155.0, ceiling.route)                               # near the middle
    assert mid < 30e3


@pytest.mark.parametrize("values,why", [
    ({"NAV_WMM": 1, "NAV_YEAR": 2026.5}, "WMM2020 covers 2019.94..2025.00, not NAV_YEAR 2026.5"),
    ({"NAV_WMM": 2, "NAV_YEAR": 2020.5}, "WMM2025 covers 2024.87..2030.00"),
    ({"NAV_PROBE1_DEG": 90.0, "NAV_PROBE2_DEG": 272.0}, "within 11.5 deg of parallel"),
    ({"NAV_PROBE1_DEG": 0.0, "NAV_PROBE2_DEG": 10.0}, "within 11.5 deg of parallel"),   # the gradient refused it
])
def test_values_in_range_that_no_mission_can_fly_together_are_refused(values, why):
    """Each in range; together the mission's constructor raised (no model for the year) or the
    probing failed (parallel moves). validate_all names the clash; the registry's defaults and
    every bundled scenario pass, and so does a model that covers the year."""
    with pytest.raises(ParamError, match=re.escape(why)):
        validate_all(values)
    validate_all({})
    validate_all({"NAV_WMM": 2, "NAV_YEAR": 2026.5, "NAV_PROBE2_DEG": 96.0})
    for path in SCENARIO_DIR.glob("*.toml"):
        validate_all(load_scenario(path.stem).nav_overrides())

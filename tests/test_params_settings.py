"""The settings classes are built from the registry: every field is one registry entry, in the
unit its name says, and a class cannot declare a field or a default of its own.

Oracles: the registry's own declarations (group, field, scale, default, frozen) and the unit
suffixes of companion/__init__.py's naming convention, written out below by hand.
"""
from __future__ import annotations

import dataclasses
import importlib
import pkgutil

import pytest

import companion.nav
from companion import params
from companion.nav.config import NavConfig
from companion.nav.navfilter import BiasSpec, FilterSettings
from companion.registry import REGISTRY, SPEC_BY_FIELD, SPEC_BY_NAME, from_values, hold_frozen, settings

# the unit a field's name promises -> the (registry unit, scale) pairs that deliver it; longest first
UNIT_SUFFIXES = {
    "_deg_per_m": {("deg/km", 1e-3)},
    "_deg_rth": {("deg/rt(h)", 1.0)},
    "_nt_rth": {("nT/rt(h)", 1.0)},
    "_deg_rkm": {("deg/rt(km)", 1.0)},
    "_nt_rkm": {("nT/rt(km)", 1.0)},
    "_mps_rth": {("m/s/rt(h)", 1.0)},
    "_mps_rts": {("m/s/rt(s)", 1.0)},
    "_arcsec": {("arcsec", 1.0)},
    "_degph": {("deg/h", 1.0)},
    "_dps": {("deg/s", 1.0)},
    "_mps": {("m/s", 1.0), ("km/h", 1.0 / 3.6)},
    "_deg": {("deg", 1.0)},
    "_nt": {("nT", 1.0)},
    "_m2": {("km^2", 1e6)},
    "_hz": {("Hz", 1.0)},
    "_m": {("m", 1.0), ("km", 1e3)},
    "_s": {("s", 1.0)},
    "_h": {("h", 1.0)},
}


def _settings_classes() -> dict[str, type]:
    """Every class built by ``companion.registry.settings``: the navigation core's (all its
    modules imported) and the companion's."""
    for module in pkgutil.iter_modules(companion.nav.__path__):
        importlib.import_module(f"companion.nav.{module.name}")
    found = {}
    for module in [params] + [importlib.import_module(f"companion.nav.{m.name}")
                              for m in pkgutil.iter_modules(companion.nav.__path__)]:
        for value in vars(module).values():
            if isinstance(value, type) and "settings_group" in vars(value):
                found[value.settings_group] = value
    return found


def test_every_settings_field_is_exactly_one_registry_entry_and_back():
    classes = _settings_classes()
    assert set(classes) == {spec.group for spec in REGISTRY if spec.group is not None}
    seen = []
    for group, cls in classes.items():
        for f in dataclasses.fields(cls):
            if "param" not in f.metadata:      # a nested settings group, nothing else
                assert hasattr(f.default_factory, "settings_group"), (cls, f.name)
                continue
            spec = SPEC_BY_NAME[f.metadata["param"]]
            assert (spec.group, spec.field) == (group, f.name)
            assert f.default == spec.field_value(spec.kind(spec.default)), spec.name
            seen.append(spec.name)
    assert sorted(seen) == sorted(SPEC_BY_FIELD[key].name for key in SPEC_BY_FIELD)
    assert len(seen) == len(set(seen))


def test_a_field_name_promises_the_unit_its_entry_delivers():
    for spec in SPEC_BY_FIELD.values():
        suffix = next((s for s in UNIT_SUFFIXES if spec.field.endswith(s)), None)
        if suffix is None:
            assert spec.scale == 1.0, f"{spec.name}: a converted value needs a field named for its unit"
            continue
        assert (spec.unit, spec.scale) in UNIT_SUFFIXES[suffix], (spec.name, spec.field, spec.unit, spec.scale)


def test_a_class_cannot_hold_a_field_or_a_default_of_its_own():
    with pytest.raises(RuntimeError, match="no registry entry"):
        @settings("fusion")
        class Extra:
            qc_m2: float
            rc_m2: float
            p0_m2: float
            feedback: int
            gain: float
    with pytest.raises(RuntimeError, match="no default of its own"):
        @settings("fusion")
        class Defaulted:
            qc_m2: float = 50e3
            rc_m2: float
            p0_m2: float
            feedback: int
    with pytest.raises(RuntimeError, match=r"no field for registry group 'fusion' field\(s\) \['feedback'\]"):
        @settings("fusion")
        class Missing:
            qc_m2: float
            rc_m2: float
            p0_m2: float


def test_the_registry_wins_where_the_filter_once_kept_its_own_defaults():
    """The filter's classes defaulted to other values than the companion flew (FUS_BQ_DEG 0.002
    against BiasSpec's 0.0002, ...); now their defaults are the registry's."""
    bias, flt = BiasSpec(), FilterSettings()
    assert (bias.q_deg_rth, bias.q_nt_rth) == (SPEC_BY_NAME["FUS_BQ_DEG"].default, SPEC_BY_NAME["FUS_BQ_NT"].default)
    assert bias.local_length_m == SPEC_BY_NAME["FUS_GM_KM"].default * 1e3
    assert flt.attitude_from_ins == SPEC_BY_NAME["FUS_ATT_INS"].default
    assert NavConfig().filter == flt and from_values(FilterSettings, {"FUS_BQ_DEG": 0.01}).bias.q_deg_rth == 0.01


def test_frozen_entries_are_held_in_nested_settings_too():
    old = NavConfig()
    new = NavConfig.from_values({"FUS_BQ_DEG": 0.01, "FUS_BQA_N": 99.0, "NAV_DEST_LAT": 27.5, "MPC_HORIZON": 4})
    merged, deferred = hold_frozen(old, new)
    assert sorted(deferred) == ["FUS_BQ_DEG", "NAV_DEST_LAT"]
    assert merged.filter.bias.q_deg_rth == old.filter.bias.q_deg_rth and merged.dest_lat_deg == old.dest_lat_deg
    assert merged.filter.bias.qa_n_nt_rth == 99.0 and merged.horizon == 4
    assert hold_frozen(old, old) == (old, [])

"""Everything derived from the one parameter registry (:mod:`companion.registry`).

Every tunable value of the companion is declared once in :data:`REGISTRY` (name of at most
16 characters for MAVLink, type, default, range, unit, description; re-exported here). From it
come:

* the frozen dataclasses the code reads (:class:`NavConfig` and the settings it nests, built by
  :func:`companion.registry.settings` in the navigation core, :class:`CompanionConfig`); the
  *readings* (:data:`READINGS`: measurements a ground station keeps up to date, such as Kp) are
  not settings and reach no dataclass: the companion's control step reads them from the server
  while they are fresh,
* ArduPilot-style ``.parm`` files (``NAME VALUE`` per line, ``#`` comments),
* the MAVLink parameter server (``companion.io.param_server``),
* the generated parameter reference (:mod:`fcmpc.paramdoc`: ``params/defaults.parm``,
  ``docs/parameters.md``, ``docs/parameters.json``; ``fcmpc-params --write``).

Defaults are the paper's Table 4 where the paper gives a value. Loading rejects unknown
names and out-of-range values with a :class:`ParamError` that names the parameter, the
file and line, and the allowed range.

>>> cfg = NavConfig.from_values(default_values())
>>> cfg.horizon, cfg.speed_mps
(2, 13.88888888888889)
"""
from __future__ import annotations

import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Iterable, Mapping

from companion.nav.config import Controller, NavConfig
from companion.nav.gradient import MIN_MOVE_SINE   # the core's own bounds
from companion.nav.wmm import MAP_WMMHR, WMM_NAMES, load_wmm, model_for_setting
from companion.registry import READINGS, REGISTRY, SPEC_BY_NAME, ParamError, ParamSpec, from_values, settings

__all__ = ["ParamSpec", "ParamError", "READINGS", "REGISTRY", "SPEC_BY_NAME", "default_values", "validate",
           "validate_all", "combination_error", "read_parm_file", "write_parm_file", "NavConfig", "CompanionConfig",
           "Controller", "write_text_atomically"]


def default_values() -> dict[str, float | int]:
    """Every parameter at its default."""
    return {spec.name: spec.kind(spec.default) for spec in REGISTRY}


def validate(name: str, value: float) -> float | int:
    """The value coerced to the parameter's type; ParamError for unknown names or bad values."""
    spec = SPEC_BY_NAME.get(name.upper())
    if spec is None:
        raise ParamError(f"unknown parameter {name!r}")
    return spec.coerce(value)


def validate_all(values: Mapping[str, float]) -> dict[str, float | int]:
    """Defaults overlaid with validated values; ParamError also for values that are each in range
    but cannot be flown together (:func:`combination_error`)."""
    merged = default_values()
    for name, value in values.items():
        merged[name.upper()] = validate(name, value)
    why = combination_error(merged)
    if why is not None:
        raise ParamError(why)
    return merged


def combination_error(values: Mapping[str, float]) -> str | None:
    """Why these values, each within its range, cannot make a mission (None: they can): a field
    model forced by NAV_WMM, or the map NAV_MAP chose, that does not cover NAV_YEAR, or probing headings NAV_PROBE1_DEG and
    NAV_PROBE2_DEG within 11.5 degrees of parallel (the gradient needs two independent moves)."""
    name = WMM_NAMES.get(int(values["NAV_WMM"]))
    year = float(values["NAV_YEAR"])
    if int(values.get("NAV_MAP", 0)) == MAP_WMMHR:
        try:
            model_for_setting(year, 0, MAP_WMMHR)
        except ValueError as err:
            return str(err)
    elif name is not None:
        model = load_wmm(name)
        if not model.valid_from <= year < model.valid_until:
            return (f"{name} covers {model.valid_from:.2f}..{model.valid_until:.2f}, not NAV_YEAR {year:g} "
                    f"(NAV_WMM {int(values['NAV_WMM'])}; 0 picks the model by date)")
    apart = math.radians(float(values["NAV_PROBE2_DEG"]) - float(values["NAV_PROBE1_DEG"]))
    if abs(math.sin(apart)) < MIN_MOVE_SINE:
        least_deg = math.degrees(math.asin(MIN_MOVE_SINE))
        return (f"NAV_PROBE1_DEG {values['NAV_PROBE1_DEG']:g}, NAV_PROBE2_DEG {values['NAV_PROBE2_DEG']:g}: within "
                f"{least_deg:.1f} deg of parallel (the gradient needs two independent moves)")
    return None


def read_parm_file(path: str | os.PathLike) -> dict[str, float | int]:
    """Parameters of an ArduPilot ``.parm`` file (``NAME VALUE`` or ``NAME,VALUE``; ``#`` comments).

    Only the names in the file are returned (overlay them with :func:`validate_all`).
    Raises ParamError naming the file and line of the first bad entry.
    """
    values: dict[str, float | int] = {}
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").replace("\t", " ").split()
        if len(parts) != 2:
            raise ParamError(f"{path}:{number}: expected 'NAME VALUE', got {raw.strip()!r}")
        name = parts[0].upper()
        try:
            value = validate(parts[0], parts[1])
        except ParamError as err:
            raise ParamError(f"{path}:{number}: {err}") from None
        if name in values:
            raise ParamError(f"{path}:{number}: {name} is set twice in this file")
        values[name] = value
    return values


def format_value(value: float | int) -> str:
    """Shortest text that reads back to the same float32-representable value."""
    return str(value) if isinstance(value, int) else repr(float(value))


def write_parm_file(path: str | os.PathLike, values: Mapping[str, float | int], header: str = "") -> None:
    """Write ``values`` atomically (:func:`write_text_atomically`).

    Values are validated first (ParamError, nothing written), so the file always reads back.
    """
    checked = {name.upper(): validate(name, value) for name, value in values.items()}
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    lines += [f"{name} {format_value(checked[name])}" for name in sorted(checked)]
    write_text_atomically(path, "\n".join(lines) + "\n")


def write_text_atomically(path: str | os.PathLike, text: str) -> None:
    """Write ``text``: temporary file in the same folder, fsync, rename.

    A crash at any moment leaves either the old file or the new one, never a half-written one;
    a replaced file keeps its permissions (a new one gets the usual 0666 less the umask).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = target.stat().st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        os.fchmod(fd, mode)  # mkstemp makes 0600
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(target.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)  # make the rename itself durable
    finally:
        os.close(dir_fd)


# --- the settings classes derived from the registry ----------------------------------------------
# NavConfig (and the filter's, fusion's and model error's settings it nests) are the navigation
# core's own classes, built by companion.registry.settings; CompanionConfig is the process's.


@settings("companion")
class CompanionConfig:
    """What the companion process needs around the core: rates, timeouts, calibration."""

    setpoint_rate_hz: float
    arm_enable: int
    position_publish: int
    heading_source: int
    feed_accuracy_m: float
    feed_blend_mps: float
    feed_accel_mps2: float
    mag_rate_hz: float
    trim_max_deg: float
    cal_turns: int
    cal_rate_dps: float
    mag_timeout_s: float
    att_timeout_s: float
    heartbeat_timeout_s: float
    spike_nt: float
    diverge_m: float
    mag_ofs_x: float
    mag_ofs_y: float
    mag_ofs_z: float
    mag_scale_x: float
    mag_scale_y: float
    mag_scale_z: float
    mag_soft_xy: float
    mag_soft_xz: float
    mag_soft_yz: float
    mag_rot_roll: float
    mag_rot_pit: float
    mag_rot_yaw: float

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> CompanionConfig:
        """Validated values (ParamError otherwise), the failsafe timeouts capped by SAFE_TMO_S."""
        merged = validate_all({k: v for k, v in values.items() if k in SPEC_BY_NAME})
        base = from_values(cls, merged)
        ceiling = float(merged["SAFE_TMO_S"])   # the start-up ceiling: a link-set timeout cannot exceed it
        return replace(base, mag_timeout_s=min(base.mag_timeout_s, ceiling),
                       att_timeout_s=min(base.att_timeout_s, ceiling),
                       heartbeat_timeout_s=min(base.heartbeat_timeout_s, ceiling))

    @property
    def feed_accel_limit_mps2(self) -> float:
        """The position feed's turn limit: COMP_FEED_ACCEL, its 0 meaning none (the feed steps)."""
        return self.feed_accel_mps2 or math.inf

    @property
    def mag_offset_mgauss(self) -> tuple[float, float, float]:
        return self.mag_ofs_x, self.mag_ofs_y, self.mag_ofs_z

    @property
    def mag_scale(self) -> tuple[float, float, float]:
        return self.mag_scale_x, self.mag_scale_y, self.mag_scale_z

    @property
    def mag_soft_xy_xz_yz(self) -> tuple[float, float, float]:
        return self.mag_soft_xy, self.mag_soft_xz, self.mag_soft_yz

    @property
    def mag_rotation_deg(self) -> tuple[float, float, float]:
        return self.mag_rot_roll, self.mag_rot_pit, self.mag_rot_yaw


def names_with_prefix(prefixes: Iterable[str]) -> list[str]:
    """Registry names starting with any of the prefixes, in registry order."""
    prefixes = tuple(prefixes)
    return [spec.name for spec in REGISTRY if spec.name.startswith(prefixes)]


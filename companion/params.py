"""Everything derived from the one parameter registry (:mod:`companion.registry`).

Every tunable value of the companion is declared once in :data:`REGISTRY` (name of at most
16 characters for MAVLink, type, default, range, unit, description; re-exported here). From it
come:

* the frozen dataclasses the code reads (:class:`NavConfig`, :class:`CompanionConfig`); the
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
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Iterable, Mapping

from companion.registry import READINGS, REGISTRY, SPEC_BY_NAME, ParamError, ParamSpec

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
    from companion.nav.gradient import MIN_MOVE_SINE   # the core's own bounds (here: no import cycle)
    from companion.nav.wmm import MAP_WMMHR, WMM_NAMES, load_wmm, model_for_setting

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


# --- dataclasses derived from the registry -------------------------------------------------


class Controller:
    """Values of NAV_CONTROLLER."""

    LTI = 0
    LTV = 1
    FC = 2
    NAMES = {0: "LTI-MPC", 1: "LTV-MPC", 2: "Fc-MPC"}


def _from(name: str, scale: float = 1.0):
    """A dataclass field defaulting to a registry parameter (times ``scale`` for unit changes)."""
    spec = SPEC_BY_NAME[name]
    value = spec.kind(spec.default) if scale == 1.0 else spec.default * scale
    return field(default=value, metadata={"param": name, "scale": scale})


class _FromRegistry:
    @classmethod
    def from_values(cls, values: Mapping[str, float]):
        """Build from parameter values (unknown names ignored here; validate first)."""
        kwargs = {}
        for f in fields(cls):  # type: ignore[arg-type]
            name = f.metadata.get("param")
            if name is not None and name in values:
                kwargs[f.name] = values[name] * f.metadata["scale"] if f.metadata["scale"] != 1.0 else values[name]
        return cls(**kwargs)


_KM2_TO_M2 = 1e6
_KMH_TO_MPS = 1.0 / 3.6


@dataclass(frozen=True)
class NavConfig(_FromRegistry):
    """What the pure navigation core needs: mission, gradient, MPC and fusion settings (SI).
    The space-weather readings (:data:`READINGS`) come with each step's measurement instead."""

    start_lat_deg: float = _from("NAV_START_LAT")
    start_lon_deg: float = _from("NAV_START_LON")
    dest_lat_deg: float = _from("NAV_DEST_LAT")
    dest_lon_deg: float = _from("NAV_DEST_LON")
    alt_m: float = _from("NAV_ALT_M")
    year: float = _from("NAV_YEAR")
    wmm: int = _from("NAV_WMM")
    nav_map: int = _from("NAV_MAP")
    speed_mps: float = _from("NAV_SPEED_KMH", _KMH_TO_MPS)
    period_s: float = _from("NAV_PERIOD_S")
    arrive_m: float = _from("NAV_ARRIVE_M")
    arrive_legs: int = _from("NAV_ARRIVE_LEGS")
    final_leg: int = _from("NAV_FINAL_LEG")
    lookahead_m: float = _from("NAV_LOOKAHEAD_M")
    max_steps: int = _from("NAV_MAX_STEPS")
    probe1_deg: float = _from("NAV_PROBE1_DEG")
    probe2_deg: float = _from("NAV_PROBE2_DEG")
    controller: int = _from("NAV_CONTROLLER")
    speed_mode: int = _from("NAV_SPEED_MODE")
    grad_update: int = _from("GRAD_UPDATE")
    grad_min_move_m: float = _from("GRAD_MIN_MOVE_M")
    horizon: int = _from("MPC_HORIZON")
    q_d: float = _from("MPC_Q_D")
    q_i: float = _from("MPC_Q_I")
    f_d: float = _from("MPC_F_D")
    f_i: float = _from("MPC_F_I")
    r_x: float = _from("MPC_R_X")
    r_y: float = _from("MPC_R_Y")
    mpc_units: int = _from("MPC_UNITS")
    u_bounds: int = _from("MPC_U_BOUNDS")
    u_max_mps: float = _from("MPC_U_MAX_KMH", _KMH_TO_MPS)
    s_min_d: float = _from("MPC_S_MIN_D")
    s_min_i: float = _from("MPC_S_MIN_I")
    s_max_d: float = _from("MPC_S_MAX_D")
    s_max_i: float = _from("MPC_S_MAX_I")
    s_min_f: float = _from("MPC_S_MIN_F")
    s_max_f: float = _from("MPC_S_MAX_F")
    s_auto: int = _from("MPC_S_AUTO")
    s_margin_deg: float = _from("MPC_S_MARGIN")
    s_admit: int = _from("MPC_S_ADMIT")
    elements: int = _from("NAV_ELEMENTS")
    calibrate: int = _from("NAV_CALIBRATE")
    fix_gate_m: float = _from("NAV_FIX_GATE_M")
    model_err_deg: float = _from("NAV_MERR_DEG")
    model_err_nt: float = _from("NAV_MERR_NT")
    model_err_length_m: float = _from("NAV_MERR_KM", 1000.0)
    reanchor_steps: int = _from("NAV_REANCHOR_N")
    dr_heading: int = _from("NAV_DR_HDG")
    solver: int = _from("MPC_SOLVER")
    fusion_sigma_deg_per_m: float = _from("FUS_SIGMA", 1e-3)
    fusion_qc_m2: float = _from("FUS_QC_KM2", _KM2_TO_M2)
    fusion_rc_m2: float = _from("FUS_RC_KM2", _KM2_TO_M2)
    fusion_p0_m2: float = _from("FUS_P0_KM2", _KM2_TO_M2)
    fusion_feedback: int = _from("FUS_FEEDBACK")
    fusion_model: int = _from("FUS_MODEL")
    filter_r_deg: float = _from("FUS_R_DEG")
    filter_r_nt: float = _from("FUS_R_NT")
    filter_r_source: int = _from("FUS_R_SRC")
    filter_rmin_deg: float = _from("FUS_RMIN_DEG")
    filter_rmin_nt: float = _from("FUS_RMIN_NT")
    bias_sigma0_deg: float = _from("FUS_B0_DEG")
    bias_sigma0_nt: float = _from("FUS_B0_NT")
    bias_q_deg: float = _from("FUS_BQ_DEG")
    bias_q_nt: float = _from("FUS_BQ_NT")
    bias_qd_deg: float = _from("FUS_BQD_DEG")
    bias_qd_nt: float = _from("FUS_BQD_NT")
    bias_qa_deg: float = _from("FUS_BQA_DEG")
    bias_qa_nt: float = _from("FUS_BQA_NT")
    bias_qa_adapt: int = _from("FUS_BQA_ADAPT")
    bias_qa_mode: int = _from("FUS_BQA_MODE")
    bias_qa_n_nt: float = _from("FUS_BQA_N")
    bias_qa_e_nt: float = _from("FUS_BQA_E")
    bias_qa_z_nt: float = _from("FUS_BQA_Z")
    bias_qa_tn_h: float = _from("FUS_BQA_TN")
    bias_qa_te_h: float = _from("FUS_BQA_TE")
    bias_qa_tz_h: float = _from("FUS_BQA_TZ")
    bias_qa_rne: float = _from("FUS_BQA_RNE")
    bias_qa_rnz: float = _from("FUS_BQA_RNZ")
    bias_qa_rez: float = _from("FUS_BQA_REZ")
    kp_on: float = _from("FUS_KP_ON")
    symh_on_nt: float = _from("FUS_SYMH_ON")
    symh_ratio: float = _from("FUS_SYMH_K")
    symh_residual_n_nt: float = _from("FUS_SYMH_N")
    symh_residual_tn_h: float = _from("FUS_SYMH_TN")
    symh_residual_rne: float = _from("FUS_SYMH_RNE")
    symh_residual_rnz: float = _from("FUS_SYMH_RNZ")
    attitude_from_ins: int = _from("FUS_ATT_INS")
    bias_heading_deg: float = _from("FUS_BH_DEG")
    bias_heading_nt: float = _from("FUS_BH_NT")
    local_err_deg: float = _from("FUS_GM_DEG")
    local_err_nt: float = _from("FUS_GM_NT")
    local_err_length_m: float = _from("FUS_GM_KM", 1000.0)
    ins_tilt_arcsec: float = _from("FUS_INS_TILT")
    ins_azimuth_arcsec: float = _from("FUS_INS_AZ")
    ins_vel_err_mps: float = _from("FUS_INS_VEL")
    ins_pos_err_m: float = _from("FUS_INS_POS")
    ins_gyro_bias_degph: float = _from("FUS_INS_GB")
    ins_gyro_markov_degph: float = _from("FUS_INS_GM")
    ins_gyro_markov_tau_s: float = _from("FUS_INS_GM_TAU")
    ins_vrw_mps_rts: float = _from("FUS_INS_VRW")
    dr_pos_sigma_m: float = _from("FUS_DR_POS_M")
    current_sigma_mps: float = _from("FUS_CUR_MPS")
    current_q_mps: float = _from("FUS_CUR_Q")
    gps_sigma_m: float = _from("FUS_GPS_M")
    grad_init: int = _from("GRAD_INIT")

    def replace(self, **changes) -> "NavConfig":
        """A copy with some fields changed (for scripts and tests)."""
        from dataclasses import replace

        return replace(self, **changes)


@dataclass(frozen=True)
class CompanionConfig(_FromRegistry):
    """What the companion process needs around the core: rates, timeouts, calibration."""

    setpoint_rate_hz: float = _from("COMP_SP_RATE_HZ")
    arm_enable: int = _from("COMP_ARM_ENABLE")
    position_publish: int = _from("COMP_POS_PUB")
    heading_source: int = _from("COMP_HEADING_SRC")
    feed_accuracy_m: float = _from("COMP_FEED_ACC_M")
    feed_blend_mps: float = _from("COMP_FEED_BLEND")
    mag_rate_hz: float = _from("COMP_MAG_HZ")
    trim_max_deg: float = _from("COMP_TRIM_DEG")
    cal_turns: int = _from("COMP_CAL_TURNS")
    cal_rate_dps: float = _from("COMP_CAL_DPS")
    mag_timeout_s: float = _from("COMP_MAG_TMO_S")
    att_timeout_s: float = _from("COMP_ATT_TMO_S")
    heartbeat_timeout_s: float = _from("COMP_HB_TMO_S")
    spike_nt: float = _from("COMP_SPIKE_NT")
    diverge_m: float = _from("COMP_DIVERGE_KM", 1e3)
    mag_offset_mgauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    mag_soft_xy_xz_yz: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> "CompanionConfig":
        base = super().from_values(values)
        merged = validate_all({k: v for k, v in values.items() if k in SPEC_BY_NAME})
        from dataclasses import replace

        ceiling = float(merged["SAFE_TMO_S"])   # the start-up ceiling: a link-set timeout cannot exceed it
        return replace(
            base,
            mag_timeout_s=min(base.mag_timeout_s, ceiling),
            att_timeout_s=min(base.att_timeout_s, ceiling),
            heartbeat_timeout_s=min(base.heartbeat_timeout_s, ceiling),
            mag_offset_mgauss=tuple(float(merged[f"MAG_OFS_{a}"]) for a in "XYZ"),
            mag_scale=tuple(float(merged[f"MAG_SCALE_{a}"]) for a in "XYZ"),
            mag_soft_xy_xz_yz=tuple(float(merged[f"MAG_SOFT_{a}"]) for a in ("XY", "XZ", "YZ")),
        )


def names_with_prefix(prefixes: Iterable[str]) -> list[str]:
    """Registry names starting with any of the prefixes, in registry order."""
    prefixes = tuple(prefixes)
    return [spec.name for spec in REGISTRY if spec.name.startswith(prefixes)]


"""Scenarios: a mission, a vehicle, its sensors, its INS, an optional storm and faults, from TOML.

One scenario file drives the in-process Monte Carlo and the MAVLink simulator alike
(``sitl/scenarios/*.toml``; ``--scenario pacific`` names a bundled one, a path names any
file). Bad files raise :class:`ScenarioError` naming the file and the key. The bundled presets are
realistic unless their name starts with ``paper_`` (the paper's idealised worlds, whose gifts to
the navigator :func:`sitl.gifts.gifts` lists); the older ``*_real`` names are aliases of the
realistic ones (:data:`ALIASES`).

Tables: ``[mission]``, ``[vehicle]``, ``[sensors]`` (including the calibration residuals and
``inprocess_samples``), ``[ins]``, ``[storm]``, ``[[faults]]``, and for the realistic world
``[field]`` (``main = "wmm" | "igrf14"``, ``crust = "emm2017" | "none"`` with ``crust_min_degree``,
``crust_max_degree``; ``crustal = true`` with ``crustal_rms_down_nt``,
``crustal_correlation_length_m``, ``crustal_waves``) and ``[attitude]`` (``heading_source =
"true" | "ins" | "magnetic"``, exposed as ``Scenario.heading_source``; biases, drift, tilt), and
in ``[vehicle]`` the motion errors (``current_mps``, ``speed_scale_sigma``, ``course_bias_deg``,
``Scenario.motion``). ``[storm]`` names a row of the storm library (``event``,
:mod:`sitl.storms.events`) and how its indices are published (``kp_delay_s``, ``kp_error``,
``ring_delay_s``, ``ring_batch_s``, ``ring_offset_nt``, ``ring_error_nt``: :mod:`sitl.storms.published`).
Absent tables leave the paper's ideal world, except the start: the vehicle
starts where a GPS fix with ``[sensors] gps_noise_m`` puts it around ``[mission] start`` (the start the
navigator is given) unless ``[mission] exact_start = true`` (:func:`sitl.world.vehicle.true_start`).
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

from sitl.storms.published import KP_NOWCAST, RING_QUICKLOOK, Publication
from sitl.world.attitude import AttitudeErrorConfig
from sitl.world.checks import require
from sitl.world.crustal import CrustalConfig
from sitl.world.ins import InsErrorConfig
from sitl.world.magerrors import MagErrorConfig
from sitl.world.vehicle import MotionErrorConfig, VehicleLimits, true_start

__all__ = ["Scenario", "SensorModel", "StormConfig", "FieldConfig", "Fault", "ScenarioError", "load_scenario",
           "ins_declaration", "ALIASES", "PAPER_PREFIX", "SCENARIO_DIR", "MAIN_FIELD_MODELS"]

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
PAPER_PREFIX = "paper_"              # a bundled preset named so is one of the paper's idealised worlds
# the realistic presets' names before they took the plain ones (issue 46)
ALIASES = {"pacific_real": "pacific", "long_storm_real": "long_storm", "short_storm_real": "short_storm"}
FAULT_KINDS = ("mag_off", "mag_stuck", "mag_spike", "mag_nan", "gps_off", "heartbeat_off",
               "link_loss", "link_delay", "link_duplicate", "storm_onset", "fc_reboot")


class ScenarioError(ValueError):
    """A scenario file that cannot be used."""


@dataclass(frozen=True)
class SensorModel:
    """Sensor imperfections (per sample unless said otherwise)."""

    mag_rate_hz: float = 10.0
    mag_noise_nt: float = 150.0          # white noise per axis, AK8963-like
    mag_bias_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)  # uncalibrated hard iron
    mag_lsb_nt: float = 100.0            # RAW_IMU carries milligauss integers
    imu_rate_hz: float = 10.0
    accel_noise_mps2: float = 0.02
    gyro_noise_radps: float = 0.0005
    attitude_noise_deg: float = 0.05     # white error of the autopilot's ATTITUDE estimate
    gps_noise_m: float = 2.5
    gps_denied_after_s: float = 0.0      # GPS has no fix from this mission time on
    # calibration residuals drawn per run (sitl.world.magerrors), 1-sigma; 0 = absent
    mag_hard_iron_resid_nt: float = 0.0
    mag_soft_iron_resid: float = 0.0
    mag_temp_coeff_nt_per_k: float = 0.0
    mag_temp_swing_k: float = 0.0
    # in-process Monte Carlo: False = the analytic averaged draw below (the paper's ideal world),
    # True = every magnetometer and attitude sample simulated and averaged as the companion does
    inprocess_samples: bool = False

    def __post_init__(self) -> None:
        require(self, ("mag_rate_hz", "imu_rate_hz"), lambda v: v > 0.0, "a finite positive rate")
        require(self, ("mag_noise_nt", "mag_lsb_nt", "accel_noise_mps2", "gyro_noise_radps", "attitude_noise_deg",
                       "gps_noise_m", "gps_denied_after_s", "mag_hard_iron_resid_nt", "mag_soft_iron_resid",
                       "mag_temp_coeff_nt_per_k", "mag_temp_swing_k"), lambda v: v >= 0.0,
                "finite and not negative (a 1-sigma, a size or a time)")

    @property
    def mag_errors(self) -> MagErrorConfig:
        """The calibration-residual sizes as a :class:`MagErrorConfig`."""
        return MagErrorConfig(self.mag_hard_iron_resid_nt, self.mag_soft_iron_resid,
                              self.mag_temp_coeff_nt_per_k, self.mag_temp_swing_k)

    def averaged_di_noise_deg(self, period_s: float, horizontal_nt: float, total_nt: float) -> tuple[float, float]:
        """1-sigma (D, I) error in degrees of the field averaged over one control period.

        The Monte Carlo draws its measurement noise from this, so it sees what the companion
        sees after averaging the simulator's samples: per-sample noise / sqrt(samples), with
        the attitude noise projected onto the field (it averages too).
        """
        samples = max(1.0, self.mag_rate_hz * period_s)
        att = math.radians(self.attitude_noise_deg)
        sigma_d = math.hypot(self.mag_noise_nt / horizontal_nt, att * total_nt / horizontal_nt)
        sigma_i = math.hypot(self.mag_noise_nt / total_nt, att)
        return math.degrees(sigma_d / math.sqrt(samples)), math.degrees(sigma_i / math.sqrt(samples))


@dataclass(frozen=True)
class StormConfig:
    """Which storm window drives the disturbance and how its time maps onto mission time; and
    which of its space-weather indices reach the navigator (the ground station's feed: the
    companion's ``NAV_KP`` and ``NAV_SYMH``, in-process the step's readings). An index not fed is
    NaN to the navigator, as for an operator without that service; the storm is the same."""

    enabled: bool = False
    event: str = "may2024"               # a row of the storm library (sitl/storms/events.toml)
    window_utc: tuple[str, str] = ("2024-05-10T18:00:00Z", "2024-05-11T00:00:00Z")
    time_map: str = "compress"           # "compress": window onto expected duration; "utc": real time
    scale: float = 1.0
    stations: tuple[str, ...] = ()       # empty: the event's stations
    kp_feed: bool = True                 # Kp (the storm's, or a quiet day's) reaches the navigator
    symh_feed: bool = True               # the ring-current index (SYM-H, else RC) reaches the navigator
    # How the indices are published (world parameters; defaults and sources in sitl.storms.published):
    # an interval's quick-look value reaches the feed delay_s after its end (ring: after the end of the
    # hourly batch holding it), off the definitive value by a per-run offset and a per-value scatter.
    kp_delay_s: float = KP_NOWCAST.delay_s
    kp_error: float = KP_NOWCAST.scatter_sigma            # 1 sigma, Kp units (rounded to thirds after)
    ring_delay_s: float = RING_QUICKLOOK.delay_s
    ring_batch_s: float = RING_QUICKLOOK.batch_s
    ring_offset_nt: float = RING_QUICKLOOK.offset_sigma   # 1 sigma, drawn once per run
    ring_error_nt: float = RING_QUICKLOOK.scatter_sigma   # 1 sigma, per value

    def __post_init__(self) -> None:
        require(self, ("kp_delay_s", "kp_error", "ring_delay_s", "ring_batch_s", "ring_offset_nt", "ring_error_nt"),
                lambda v: v >= 0.0, "finite and not negative (a delay or a 1-sigma)")

    @property
    def window_posix(self) -> tuple[float, float]:
        return tuple(_parse_utc(text).timestamp() for text in self.window_utc)  # type: ignore[return-value]

    @property
    def kp_publication(self) -> Publication:
        """How this world's Kp is published (:class:`sitl.storms.published.Publication`)."""
        return replace(KP_NOWCAST, delay_s=self.kp_delay_s, scatter_sigma=self.kp_error)

    @property
    def ring_publication(self) -> Publication:
        """How this world's ring-current index is published."""
        return replace(RING_QUICKLOOK, delay_s=self.ring_delay_s, batch_s=self.ring_batch_s,
                       offset_sigma=self.ring_offset_nt, scatter_sigma=self.ring_error_nt)


MAIN_FIELD_MODELS = ("wmm", "igrf14", "ardupilot")
CRUST_MODELS = ("none", "emm2017")


@dataclass(frozen=True)
class FieldConfig:
    """The ``[field]`` table: the truth's main-field model and its crustal anomaly field.

    ``main = "wmm"`` is the navigator's own model (the paper's ideal world: the map is the
    territory); ``"igrf14"`` is IGRF-14 (:mod:`sitl.world.igrf`); ``"ardupilot"`` ArduPilot's own
    10-degree tables, the world ArduPilot SITL flies in (:mod:`sitl.world.fc_tables`). ``crust =
    "emm2017"`` adds the real crust, EMM2017 degrees ``crust_min_degree``..``crust_max_degree``
    synthesised on the route's grid (:mod:`sitl.world.emm`); ``"none"`` leaves it out. The seeded
    anomaly field (``crustal = true``, :mod:`sitl.world.crustal`) is drawn per run from the run's
    seed: alone, an unmapped ocean's statistics; beside EMM2017, an option for the scales below its
    51 km.
    """

    main: str = "wmm"
    crustal: CrustalConfig = CrustalConfig()
    crust: str = "none"
    crust_min_degree: int = 16
    crust_max_degree: int = 790

    def __post_init__(self) -> None:
        if self.main not in MAIN_FIELD_MODELS:
            raise ValueError(f"main must be one of {', '.join(MAIN_FIELD_MODELS)}, not {self.main!r}")
        if self.crust not in CRUST_MODELS:
            raise ValueError(f"crust must be one of {', '.join(CRUST_MODELS)}, not {self.crust!r}")
        if not 1 <= self.crust_min_degree <= self.crust_max_degree:
            raise ValueError(f"crust degrees {self.crust_min_degree}-{self.crust_max_degree}: need 1 <= min <= max")


@dataclass(frozen=True)
class Fault:
    """A scheduled fault: ``kind`` from ``at_s`` (mission time) for ``duration_s``."""

    kind: str
    at_s: float
    duration_s: float = math.inf
    value: float = 0.0                   # loss fraction, delay seconds, spike nT ...

    def active(self, time_s: float) -> bool:
        return self.at_s <= time_s < self.at_s + self.duration_s


@dataclass(frozen=True)
class Scenario:
    """Everything a run needs besides the navigation parameters."""

    name: str
    description: str
    start_lat_deg: float
    start_lon_deg: float
    dest_lat_deg: float
    dest_lon_deg: float
    alt_m: float = 0.0
    year: float = 2024.36
    start_utc: str = "2024-05-10T18:00:00Z"
    # True: the vehicle starts exactly on the start the navigator is given (the paper's gift);
    # False: a GPS fix's error away from it ([sensors] gps_noise_m, drawn per run)
    exact_start: bool = False
    vehicle: VehicleLimits = VehicleLimits()
    sensors: SensorModel = SensorModel()
    ins: InsErrorConfig = InsErrorConfig()
    storm: StormConfig = StormConfig()
    faults: tuple[Fault, ...] = field(default_factory=tuple)
    source: str = ""
    attitude: AttitudeErrorConfig = AttitudeErrorConfig()
    field_model: FieldConfig = FieldConfig()
    motion: MotionErrorConfig = MotionErrorConfig()
    # [navigator]: registry values of the navigator as set up for this world (the ideal presets
    # tell it that its field model is the truth); any --param given by the user wins
    navigator: tuple[tuple[str, float], ...] = ()

    @property
    def heading_source(self) -> str:
        """Where the flight controller's yaw comes from: ``true``, ``ins`` or ``magnetic``."""
        return self.attitude.heading_source

    def true_start(self, rng, declared: tuple[float, float] | None = None) -> tuple[float, float]:
        """Where the vehicle truly starts, (lat, lon) in degrees: the start the navigator is given
        (``declared``, default ``[mission] start``: a GPS fix before take-off) less a receiver error of
        ``[sensors] gps_noise_m`` drawn from ``rng`` (:func:`sitl.world.vehicle.true_start`); the
        declared start itself with ``exact_start``."""
        lat, lon = declared if declared is not None else (self.start_lat_deg, self.start_lon_deg)
        if self.exact_start:
            return lat, lon
        return true_start(lat, lon, self.sensors.gps_noise_m, rng)

    @property
    def start_posix(self) -> float:
        return _parse_utc(self.start_utc).timestamp()

    def nav_overrides(self, navigator: bool = True) -> dict[str, float]:
        """Registry values this scenario sets: start, destination, altitude, date, and (unless
        ``navigator`` is False: a flight on real firmware, whose world is not this one) what an
        operator declares of the installation: where the attitude comes from (``FUS_ATT_INS``
        from ``[attitude]``) and the INS's datasheet (``FUS_INS_*`` from ``[ins]``,
        :func:`ins_declaration`), then the ``[navigator]`` table."""
        mission = {"NAV_START_LAT": self.start_lat_deg, "NAV_START_LON": self.start_lon_deg,
                   "NAV_DEST_LAT": self.dest_lat_deg, "NAV_DEST_LON": self.dest_lon_deg,
                   "NAV_ALT_M": self.alt_m, "NAV_YEAR": self.year}
        if not navigator:
            return mission
        declared = ins_declaration(self.ins) if self.ins.onboard else {}
        return {**mission, "FUS_ATT_INS": self.attitude.ins_share, **declared, **dict(self.navigator)}


def ins_declaration(ins: InsErrorConfig) -> dict[str, float]:
    """The ``FUS_INS_*`` values declaring this INS to the navigator: the 1-sigma its errors are
    drawn with (a datasheet), not the errors drawn. The two level axes' misalignments and the
    east and north position errors are declared as one value each, their RMS (rounded to 1e-6
    of the unit, so Table 1's arc-minutes read back as whole arc-seconds)."""
    tilt_arcsec = 60.0 * math.sqrt((ins.misalign_arcmin[0] ** 2 + ins.misalign_arcmin[1] ** 2) / 2.0)
    pos_m = math.sqrt((ins.pos_err_east_m ** 2 + ins.pos_err_north_m ** 2) / 2.0)
    return {"FUS_INS_TILT": round(tilt_arcsec, 6), "FUS_INS_AZ": round(60.0 * ins.misalign_arcmin[2], 6),
            "FUS_INS_VEL": ins.vel_err_mps, "FUS_INS_POS": round(pos_m, 6),
            "FUS_INS_GB": ins.gyro_bias_degph, "FUS_INS_GM": ins.gyro_markov_degph,
            "FUS_INS_GM_TAU": ins.gyro_markov_tau_s}


def _parse_utc(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00")).astimezone(timezone.utc)


def _section(data: dict, key: str, path: Path) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ScenarioError(f"{path}: [{key}] must be a table")
    return value


def _build(cls, values: dict, path: Path, section: str, convert: dict | None = None):
    known = set(cls.__dataclass_fields__)
    unknown = set(values) - known
    if unknown:
        raise ScenarioError(f"{path}: unknown key(s) in [{section}]: {', '.join(sorted(unknown))}")
    converted = {k: (convert or {}).get(k, lambda v: v)(v) for k, v in values.items()}
    try:
        return cls(**converted)
    except (TypeError, ValueError) as err:
        raise ScenarioError(f"{path}: [{section}]: {err}") from None


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A bundled scenario by name (``pacific``, ``long_storm``, ``short_storm``, their idealised
    ``paper_*`` versions, ...; an old name of :data:`ALIASES`) or a TOML path."""
    path = Path(name_or_path)
    if not path.suffix:
        path = SCENARIO_DIR / f"{ALIASES.get(str(name_or_path), name_or_path)}.toml"
    if not path.is_file():
        bundled = ", ".join(sorted(p.stem for p in SCENARIO_DIR.glob("*.toml")))
        raise ScenarioError(f"no scenario {name_or_path!r} (bundled: {bundled})")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise ScenarioError(f"{path}: {err}") from None
    unknown = set(data) - {"name", "description", "mission", "vehicle", "sensors", "ins", "storm", "faults",
                           "attitude", "field", "navigator"}
    if unknown:
        raise ScenarioError(f"{path}: unknown key(s) or table(s): {', '.join(sorted(unknown))}")
    mission = _section(data, "mission", path)
    unknown = set(mission) - {"start", "destination", "alt_m", "year", "start_utc", "exact_start"}
    if unknown:
        raise ScenarioError(f"{path}: unknown key(s) in [mission]: {', '.join(sorted(unknown))}")
    try:
        start, dest = mission["start"], mission["destination"]
        lat0, lon0, lat1, lon1 = float(start[0]), float(start[1]), float(dest[0]), float(dest[1])
    except (KeyError, IndexError, TypeError, ValueError):
        raise ScenarioError(f"{path}: [mission] needs start = [lat, lon] and destination = [lat, lon]") from None
    if not isinstance(mission.get("exact_start", False), bool):
        raise ScenarioError(f"{path}: [mission] exact_start must be true or false")
    vehicle = dict(_section(data, "vehicle", path))
    if "max_speed_kmh" in vehicle:
        vehicle["max_speed_mps"] = float(vehicle.pop("max_speed_kmh")) / 3.6
    if "turn_rate_dps" in vehicle:
        vehicle["turn_rate_radps"] = math.radians(float(vehicle.pop("turn_rate_dps")))
    # current_mps, speed_scale_sigma, course_bias_deg: the run's motion errors (sitl.world.vehicle)
    motion = {k: vehicle.pop(k) for k in list(vehicle) if k in MotionErrorConfig.__dataclass_fields__}
    ins = dict(_section(data, "ins", path))
    unit = ins.pop("misalign_unit", "arcmin")
    if unit not in ("arcmin", "arcsec"):
        raise ScenarioError(f"{path}: [ins] misalign_unit must be 'arcmin' or 'arcsec'")
    if "misalign" in ins:
        ins["misalign_arcmin"] = tuple(float(a) / (60.0 if unit == "arcsec" else 1.0) for a in ins.pop("misalign"))
    faults = []
    for index, raw in enumerate(data.get("faults", [])):
        fault = _build(Fault, raw, path, f"faults #{index + 1}")
        if fault.kind not in FAULT_KINDS:
            raise ScenarioError(f"{path}: fault #{index + 1}: kind {fault.kind!r} not one of {', '.join(FAULT_KINDS)}")
        faults.append(fault)
    storm = _build(StormConfig, _section(data, "storm", path), path, "storm",
                   {"window_utc": tuple, "stations": tuple})
    if storm.time_map not in ("compress", "utc"):
        raise ScenarioError(f"{path}: [storm] time_map must be 'compress' or 'utc'")
    field_table = dict(_section(data, "field", path))
    # crustal = true, crustal_rms_down_nt, crustal_correlation_length_m, crustal_waves
    crustal = {("enabled" if key == "crustal" else key.removeprefix("crustal_")): field_table.pop(key)
               for key in list(field_table) if key.startswith("crustal")}
    field_config = _build(FieldConfig, {**field_table, "crustal": _build(CrustalConfig, crustal, path, "field")},
                          path, "field")
    navigator = _navigator(_section(data, "navigator", path), path)
    return Scenario(
        name=str(data.get("name", path.stem)),
        description=str(data.get("description", "")),
        start_lat_deg=lat0, start_lon_deg=lon0, dest_lat_deg=lat1, dest_lon_deg=lon1,
        alt_m=float(mission.get("alt_m", 0.0)),
        year=float(mission.get("year", 2024.36)),
        start_utc=str(mission.get("start_utc", "2024-05-10T18:00:00Z")),
        exact_start=mission.get("exact_start", False),
        vehicle=_build(VehicleLimits, vehicle, path, "vehicle"),
        sensors=_build(SensorModel, _section(data, "sensors", path), path, "sensors", {"mag_bias_nt": tuple}),
        ins=_build(InsErrorConfig, ins, path, "ins", {"misalign_arcmin": tuple}),
        storm=storm,
        faults=tuple(faults),
        source=str(path),
        attitude=_build(AttitudeErrorConfig, _section(data, "attitude", path), path, "attitude"),
        field_model=field_config,
        motion=_build(MotionErrorConfig, motion, path, "vehicle"),
        navigator=navigator,
    )


def _navigator(table: dict, path: Path) -> tuple[tuple[str, float], ...]:
    """The ``[navigator]`` table, checked against the parameter registry (names and ranges)."""
    from companion.params import ParamError, validate_all

    try:
        checked = validate_all(table)
    except ParamError as err:
        raise ScenarioError(f"{path}: [navigator]: {err}") from None
    return tuple((name.upper(), checked[name.upper()]) for name in table)

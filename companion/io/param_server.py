"""MAVLink parameter server for the companion component, over :mod:`companion.params`.

Serves exactly :data:`companion.params.REGISTRY`, in registry order (``param_index``), to
PARAM_REQUEST_LIST, PARAM_REQUEST_READ (by index or name) and PARAM_SET addressed to this
system (or system 0) and to component 191 or MAV_COMP_ID_ALL (0); anything else is ignored.
A name the registry does not know, addressed to all components, belongs to another component
(the flight controller's CRUISE_SPEED) and is left alone without a word; addressed to 191 it
is refused with a STATUSTEXT.

Values
    Float parameters go out as MAV_PARAM_TYPE_REAL32, integer ones as MAV_PARAM_TYPE_INT32.
    How an INT32 travels in the float field follows the flight controller the ground station
    sees on this system (``encoding="auto"``): ArduPilot (and unknown) -> *C cast* (the float
    holds the number: what MAVProxy and MAVSDK expect of an ArduPilot system); PX4 -> *bytewise*
    (the float's bits are the int32: what MAVSDK and QGroundControl expect of a PX4 system).
    ``cast`` or ``bytewise`` force one. Before a flight controller is heard, ``auto`` casts.
    On PARAM_SET both encodings are understood whatever the mode: every valid integer of the
    registry lies in [0, 2^23), whose int32 bits read as a float are exactly the subnormal floats
    (and 0), so a subnormal value is decoded bytewise and anything else as a cast number.
    (MAVSDK encodes bytewise unless the system's autopilot is ArduPilot; MAVProxy, which keeps
    a separate parameter table per component, always casts for component 191.)

Setting
    A value outside the registry's range (or not an integer for an INT32) is refused: the reply
    is PARAM_VALUE with the *unchanged* value, plus a STATUSTEXT naming the parameter and range.
    A float32 rounding of a bound (a ground station echoing ``0.1``) counts as the bound.
    Accepted values are persisted at once with :func:`companion.params.write_parm_file`
    (temporary file, fsync, rename: a crash leaves the old or the new file, never half of one),
    then reported to ``on_change`` so the application applies them at its next control step.
    Readings (:data:`companion.registry.READINGS`: Kp, SYM-H) are kept in memory with the message
    time of their last set (:meth:`ParamServer.age_s`) and never written: a value from the file
    never counts as a reading, and in a storm SYM-H changes every minute.

Who may set
    Only ground stations whose system id is allowed (LINK_GCS_ID1/ID2, start-up only; default
    255, the conventional GCS id) and only addressed to this system (target_system 0 is refused
    for a write); with MAVLink signing on, unsigned or badly signed PARAM_SETs never reach the
    server (:mod:`companion.io.link.signing`). A stranger's write is dropped without a reply and
    counted (:attr:`ParamServer.sets_from_strangers`). Values above the start-up safety ceiling
    (:class:`companion.ceiling.SafetyCeiling`) and every start-up-only parameter are refused like
    out-of-range values. An accepted value equal to the stored one is answered but not rewritten.

Start-up
    The ``.parm`` file is read with :func:`companion.params.read_parm_file`. A missing file
    means defaults (created on the first PARAM_SET). A *broken* file (unknown name, bad or
    out-of-range value) is the unsafe case: the server serves the defaults so a ground station
    can see and inspect them, records :attr:`ParamServer.load_error`, never overwrites the
    broken file (sets then live in memory only), and the application refuses to arm or steer
    for the whole run. Fix the file (the error names file, line and range) and restart.
"""
from __future__ import annotations

import math
import os
import struct
from pathlib import Path
from typing import Callable

from companion.ceiling import SafetyCeiling
from companion.io.link import COMPANION_COMPONENT, MavlinkLink, mavlink
from companion.params import REGISTRY, SPEC_BY_NAME, ParamError, ParamSpec, combination_error, default_values, \
    read_parm_file, validate_all, write_parm_file
from companion.registry import READINGS

__all__ = ["ParamServer", "encode_value", "decode_value", "ENCODINGS"]

ENCODINGS = ("auto", "cast", "bytewise")
_INDEX = {spec.name: index for index, spec in enumerate(REGISTRY)}
_FLOAT32_REL = 2.0 ** -22   # two float32 ulps, relative


def _param_type(spec: ParamSpec) -> int:
    return mavlink.MAV_PARAM_TYPE_INT32 if spec.kind is int else mavlink.MAV_PARAM_TYPE_REAL32


def encode_value(spec: ParamSpec, value: float | int, bytewise: bool) -> float:
    """The PARAM_VALUE float of a value.

    >>> spec = SPEC_BY_NAME["NAV_MAX_STEPS"]
    >>> encode_value(spec, 1000, False), struct.pack("<f", encode_value(spec, 1000, True)) == struct.pack("<i", 1000)
    (1000.0, True)
    """
    if spec.kind is int and bytewise:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


_FLT_MIN = 1.1754943508222875e-38   # smallest normal float32
for _spec in REGISTRY:   # the decoding rule above needs every integer parameter in [0, 2^23)
    if _spec.kind is int and not (0 <= _spec.minimum and _spec.maximum < 2 ** 23):
        raise RuntimeError(f"{_spec.name}: integer range [{_spec.minimum}, {_spec.maximum}] breaks PARAM_SET decoding")


def decode_value(spec: ParamSpec, param_value: float) -> float:
    """The number a PARAM_SET carries: subnormal -> int32 bits (bytewise), else the float (cast).

    >>> spec = SPEC_BY_NAME["NAV_MAX_STEPS"]
    >>> decode_value(spec, 500.0), decode_value(spec, encode_value(spec, 500, True))
    (500.0, 500.0)
    """
    if spec.kind is int and param_value != 0.0 and abs(param_value) < _FLT_MIN:
        return float(struct.unpack("<i", struct.pack("<f", param_value))[0])
    return float(param_value)


def _snap_to_bounds(spec: ParamSpec, value: float) -> float:
    """A float32 rounding of a bound is the bound (so 0.1 sent as float32 is not 'above 0.1')."""
    for bound in (spec.minimum, spec.maximum):
        if math.isfinite(value) and abs(value - bound) <= _FLOAT32_REL * max(abs(bound), 1e-30):
            return float(bound)
    return value


class ParamServer:
    """PARAM_* protocol for one component; MAVProxy-module shaped (``mavlink_packet``/``idle_task``)."""

    def __init__(self, link: MavlinkLink, parm_path: str | os.PathLike | None = None,
                 on_change: Callable[[str, float | int], None] | None = None, encoding: str = "auto",
                 ceiling: SafetyCeiling | None = None, clock: Callable[[], float] | None = None) -> None:
        if encoding not in ENCODINGS:
            raise ValueError(f"parameter encoding {encoding!r} not one of {', '.join(ENCODINGS)}")
        self.link = link
        self.path = Path(parm_path) if parm_path else None
        self.on_change = on_change
        self.clock = clock              # message time of each accepted set (age_s): live inputs such as NAV_SYMH
        self.set_at_s: dict[str, float] = {}
        self.encoding = encoding
        self.values: dict[str, float | int] = default_values()
        self.load_error: str | None = None
        self.persist_error: str | None = None
        self.ceiling = ceiling          # None: taken from the values loaded at start (load())
        self.requests = 0
        self.sets_accepted = 0
        self.sets_refused = 0
        self.sets_from_strangers = 0
        self.writes = 0
        self.stale_removed = 0

    # --- start-up -------------------------------------------------------------------------------
    def load(self) -> bool:
        """Read the .parm file; False (defaults served, :attr:`load_error` set) if it is broken.

        Temporary files a killed writer left beside it (``.NAME.*.tmp``) are removed first. The
        safety ceiling, unless given, is fixed here from the values read.
        """
        ok = True
        if self.path is not None:
            self._remove_stale_temporaries()
        if self.path is not None and self.path.exists():
            try:
                self.values = validate_all(read_parm_file(self.path))
            except (ParamError, OSError, UnicodeDecodeError) as err:
                self.values = default_values()
                self.load_error = str(err)
                ok = False
        if self.ceiling is None:
            self.ceiling = SafetyCeiling.from_values(self.values)
        return ok

    def _remove_stale_temporaries(self) -> None:
        for stale in self.path.parent.glob(f".{self.path.name}.*.tmp"):
            try:
                stale.unlink()
                self.stale_removed += 1
            except OSError:  # pragma: no cover - not ours to remove
                pass

    @property
    def bytewise(self) -> bool:
        if self.encoding == "auto":
            return self.link.fc.detected and self.link.fc.conventions.param_bytewise
        return self.encoding == "bytewise"

    # --- receive hook ---------------------------------------------------------------------------
    def _addressed_to_us(self, msg) -> bool:
        return (msg.target_system in (0, self.link.sysid)
                and msg.target_component in (0, COMPANION_COMPONENT, self.link.component))

    def mavlink_packet(self, msg) -> bool:
        """Handle PARAM_* messages; True if the message was for this server."""
        mtype = msg.get_type()
        if mtype not in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET") or not self._addressed_to_us(msg):
            return False
        if not self.link.from_allowed_gcs(msg):
            self.sets_from_strangers += mtype == "PARAM_SET"
            return True   # a stranger gets nothing: no values, no writes, no reply
        self.requests += 1
        if mtype == "PARAM_REQUEST_LIST":
            for spec in REGISTRY:
                self.send_value(spec.name)
        elif mtype == "PARAM_REQUEST_READ":
            name = self._name_of(msg.param_id, msg.param_index)
            if name is not None:
                self.send_value(name)
        else:
            self._handle_set(msg)
        return True

    def idle_task(self) -> None:
        """Nothing periodic: replies go out at once (the whole list is 2 kB)."""

    @staticmethod
    def _clean_id(param_id) -> str:
        if isinstance(param_id, bytes):
            param_id = param_id.decode("ascii", errors="replace")
        return param_id.split("\x00", 1)[0].strip().upper()

    def _name_of(self, param_id, param_index: int) -> str | None:
        if 0 <= param_index < len(REGISTRY):
            return REGISTRY[param_index].name
        name = self._clean_id(param_id)
        return name if name in SPEC_BY_NAME else None

    def send_value(self, name: str) -> None:
        spec = SPEC_BY_NAME[name]
        self.link.mav.param_value_send(name.encode("ascii"), encode_value(spec, self.values[name], self.bytewise),
                                       _param_type(spec), len(REGISTRY), _INDEX[name])

    def _handle_set(self, msg) -> None:
        name = self._clean_id(msg.param_id)
        spec = SPEC_BY_NAME.get(name)
        if msg.target_system != self.link.sysid:   # a write addressed to every system is nobody's
            self.sets_refused += 1
            return
        if spec is None:
            if msg.target_component != 0:   # to all components: the flight controller's (CRUISE_SPEED), not ours
                self.sets_refused += 1
                self.link.send_statustext(f"FcMPC: no parameter {name[:30]}", mavlink.MAV_SEVERITY_WARNING)
            return
        raw = _snap_to_bounds(spec, decode_value(spec, msg.param_value))
        try:
            value = spec.coerce(raw)
        except ParamError:
            self.sets_refused += 1
            self.send_value(name)   # the unchanged value: the set did not happen
            if not math.isfinite(raw):
                why = "not finite"
            elif spec.kind is int and raw != round(raw):
                why = "not an integer"
            else:
                why = f"range {spec.minimum:g}..{spec.maximum:g}"
            self.link.send_statustext(f"FcMPC: {name}={raw:.6g} refused, {why}", mavlink.MAV_SEVERITY_WARNING)
            return
        why = self._ceiling().refusal(name, value, self.values)
        if why is None:   # each value in range, but together no mission (NAV_WMM against NAV_YEAR, ...)
            clash = combination_error({**self.values, name: value})
            why = None if clash is None else f"refused: {clash}"
        if why is not None:
            self.sets_refused += 1
            self.send_value(name)
            self.link.send_statustext(f"FcMPC: {name}={value:.6g} {why}"[:100], mavlink.MAV_SEVERITY_WARNING)
            return
        self.set_value(name, value)
        self.send_value(name)

    def _ceiling(self) -> SafetyCeiling:
        if self.ceiling is None:
            self.ceiling = SafetyCeiling.from_values(self.values)
        return self.ceiling

    # --- local API ------------------------------------------------------------------------------
    def set_value(self, name: str, value: float | int) -> None:
        """Store a validated value, persist it atomically (unless unchanged), report it to ``on_change``."""
        old = self.values.get(name)
        self.values[name] = value
        self.sets_accepted += 1
        if self.clock is not None:   # a repeated value is news too: the sender is still there
            self.set_at_s[name] = self.clock()
        if old == value and type(old) is type(value):
            return   # nothing changed: no rewrite, no fsync
        if name not in READINGS:   # a reading is kept in memory: one from the file never counts, and a
            self.persist()         # storm's SYM-H changes every minute (a rewrite and an fsync each)
        if self.on_change is not None:
            self.on_change(name, value)

    def age_s(self, name: str, now: float) -> float:
        """Seconds of message time since ``name`` was last set over the link (or locally), inf
        when it has not been since start: a value read from the file is not a live reading."""
        at = self.set_at_s.get(name)
        return math.inf if at is None else now - at

    def persist(self) -> bool:
        if self.path is None or self.load_error is not None:
            return False   # a broken file stays as it is, for the operator to inspect
        self.writes += 1
        try:
            # the settings only: a reading (Kp, SYM-H) from the file never counts, so it is not written
            settings = {name: value for name, value in self.values.items() if name not in READINGS}
            write_parm_file(self.path, settings, header="fcmpc companion parameters (written by the parameter server)")
        except OSError as err:
            self.persist_error = str(err)
            self.link.send_statustext(f"FcMPC: cannot save params: {err}"[:100], mavlink.MAV_SEVERITY_ERROR)
            return False
        self.persist_error = None
        return True

"""The stand-in's own parameters over the MAVLink parameter protocol, like ArduPilot (or PX4) serves them.

PARAM_REQUEST_LIST sends every parameter of :mod:`sitl.fc.param_table` (``param_index`` =
position, ``param_count`` = the table's size); PARAM_REQUEST_READ answers one, by index, or
by name when ``param_index`` is -1 (the MAVLink rule); PARAM_SET is range-checked and always
answered with PARAM_VALUE: the new value, or the unchanged one plus a STATUSTEXT naming the
allowed values when refused. Unknown names get no answer (as ArduPilot), and are counted.

Only requests addressed to this vehicle are served: ``target_system`` our system id and
``target_component`` 1 or 0. A request to another component (the companion's 191) is
routed to it untouched, so ground stations listing the companion's parameters never see ours.

Who receives the answers, as on ArduPilot (``libraries/GCS_MAVLink/GCS_Param.cpp``) and PX4
(``mavlink_parameters.cpp``, one instance per link): a list and a read are answered on the link
the request came in on only (:meth:`sitl.fc.outbox.Outbox.emit_reply`), a set on every link.
ArduPilot's answer to a read carries the request's ``param_index`` (-1, 65535 on the wire, for a
read by name) and a set's answer -1; PX4's carry the parameter's index. A ground station
downloading the companion's list (MAVSDK files every PARAM_VALUE of the system under the
download it runs, skipping index 65535 only) therefore never meets the flight controller's answers
to the companion's own reads of EK3_SRC1_YAW and COMPASS_USE.

Encoding of INT32 values in the float ``param_value``: ArduPilot sends the value converted to
float (C cast); PX4 copies the int32's four bytes (bytewise), and reads PARAM_SET the same way.
"""
from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.fc.param_table import MAV_PARAM_TYPE_INT32, ParamSpec
from sitl.guidance import SEVERITY_WARNING

__all__ = ["FcParams", "float_from_int32_bytes", "int32_from_float_bytes"]

NO_INDEX = 65535              # param_index -1 of an int16 request, as a uint16 PARAM_VALUE carries it
_F32 = struct.Struct("<f")
_I32 = struct.Struct("<i")


def float_from_int32_bytes(value: int) -> float:
    """The float whose four bytes are the int32 ``value`` (PX4's bytewise encoding).

    >>> int32_from_float_bytes(float_from_int32_bytes(15))
    15
    """
    return _F32.unpack(_I32.pack(int(value)))[0]


def int32_from_float_bytes(value: float) -> int:
    """The int32 whose four bytes are the float ``value`` (decodes PX4's bytewise encoding)."""
    return _I32.unpack(_F32.pack(value))[0]


class FcParams:
    """The flight controller's parameter table and its protocol handlers."""

    def __init__(self, specs: tuple[ParamSpec, ...], out, guidance, faults, counters, *, sysid: int, compid: int,
                 bytewise: bool = False, echo_index: bool = False) -> None:
        self.specs = {spec.name: spec for spec in specs}
        self.names = [spec.name for spec in specs]
        self.values: dict[str, float] = {spec.name: spec.default for spec in specs}
        self.out = out
        self.guidance = guidance
        self.faults = faults
        self.counters = counters
        self.sysid, self.compid = sysid, compid
        self.bytewise = bytewise
        self.echo_index = echo_index    # ArduPilot: a read's answer carries the request's index, a set's -1

    def handlers(self) -> dict:
        return {"PARAM_REQUEST_LIST": self.on_request_list, "PARAM_REQUEST_READ": self.on_request_read,
                "PARAM_SET": self.on_set}

    def _for_us(self, msg) -> bool:
        if msg.target_system == self.sysid and msg.target_component in (0, self.compid):
            return True
        self.counters.add("param_not_for_us")
        return False

    def _encode(self, spec: ParamSpec, value: float) -> float:
        if self.bytewise and spec.kind == MAV_PARAM_TYPE_INT32:
            return float_from_int32_bytes(int(value))
        return float(value)

    def _decode(self, spec: ParamSpec, value: float) -> float:
        if self.bytewise and spec.kind == MAV_PARAM_TYPE_INT32:
            return float(int32_from_float_bytes(value))
        return float(value)

    def _send(self, name: str, requested_index: int | None = None) -> None:
        """PARAM_VALUE of ``name``: the answer to a list or a read (``requested_index``, -1 by name)
        on the requesting link only; without one (a set) on every link."""
        spec = self.specs[name]
        index = self.names.index(name)
        if self.echo_index:
            index = NO_INDEX if requested_index is None or requested_index < 0 else requested_index
        fields = (name.encode(), self._encode(spec, self.values[name]), spec.kind, len(self.names), index)
        if requested_index is None:
            self.out.emit(mavlink.MAVLink_param_value_message, *fields)
        else:
            self.out.emit_reply(mavlink.MAVLink_param_value_message, *fields)

    @staticmethod
    def _name(msg) -> str:
        raw = msg.param_id
        return (raw if isinstance(raw, str) else raw.decode("ascii", "replace")).rstrip("\x00")

    def on_request_list(self, msg) -> None:
        if not self._for_us(msg):
            return
        for index, name in enumerate(self.names):
            self._send(name, index)

    def on_request_read(self, msg) -> None:
        if not self._for_us(msg):
            return
        if msg.param_index >= 0:
            if msg.param_index < len(self.names):
                self._send(self.names[msg.param_index], msg.param_index)
                return
        else:
            name = self._name(msg)
            if name in self.specs:
                self._send(name, -1)
                return
        self.counters.add("param_read_unknown")

    def on_set(self, msg) -> None:
        if not self._for_us(msg):
            return
        name = self._name(msg)
        spec = self.specs.get(name)
        if spec is None:
            self.counters.add("param_set_unknown")
            return
        value = self._decode(spec, msg.param_value)
        if spec.accepts(value):
            self.values[name] = value
            self._apply(name, value)
            self.counters.add("param_set_accepted")
        else:
            self.counters.add("param_set_refused")
            self.out.say(f"param_{name}", SEVERITY_WARNING, f"{name} refused: {spec.rule()}")
        self._send(name)

    def _apply(self, name: str, value: float) -> None:
        """The parameters that change what the simulator does."""
        if name == "CRUISE_SPEED":
            self.guidance.cruise_speed_mps = value
        elif name in ("GUID_TIMEOUT", "COM_OF_LOSS_T"):
            self.guidance.setpoint_timeout_s = value
        elif name == "SIM_GPS1_ENABLE":
            self.faults.set_gps_enabled(value != 0.0)
            self.out.say(None, SEVERITY_WARNING, f"SITL GPS1 {'enabled' if value else 'disabled'} (SIM_GPS1_ENABLE)")

"""The stand-in's own parameters over the MAVLink parameter protocol (PARAM_REQUEST_LIST/_READ, PARAM_SET).

A small read-mostly table, so ground stations finish their parameter download; PARAM_SET is
range-checked and always answered with PARAM_VALUE (the unchanged value when refused).
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.guidance import SEVERITY_WARNING

__all__ = ["MAV_PARAM_TYPE_INT32", "MAV_PARAM_TYPE_REAL32", "FcParams"]

MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32 = 6, 9


class FcParams:
    """The parameter table (name -> [value, type, (min, max) or None = read-only]) and its protocol."""

    def __init__(self, out, guidance, counters, *, sysid: int, max_speed_mps: float, speedup: float) -> None:
        self.out = out
        self.guidance = guidance
        self.counters = counters
        self.table: dict[str, list] = {
            "SYSID_THISMAV": [float(sysid), MAV_PARAM_TYPE_INT32, None],
            "FRAME_CLASS": [2.0, MAV_PARAM_TYPE_INT32, None],           # 2 = boat
            "CRUISE_SPEED": [guidance.cruise_speed_mps, MAV_PARAM_TYPE_REAL32, (0.0, max_speed_mps)],
            "GUID_TIMEOUT": [guidance.setpoint_timeout_s, MAV_PARAM_TYPE_REAL32, (0.1, 60.0)],
            "SIM_SPEEDUP": [float(speedup), MAV_PARAM_TYPE_REAL32, None],
        }

    def handlers(self) -> dict:
        return {"PARAM_REQUEST_LIST": self.on_request_list, "PARAM_REQUEST_READ": self.on_request_read,
                "PARAM_SET": self.on_set}

    def _param_value(self, name: str, index: int) -> None:
        value, kind, _ = self.table[name]
        self.out.emit(mavlink.MAVLink_param_value_message, name.encode(), float(value), kind, len(self.table), index)

    def on_request_list(self, msg) -> None:
        for index, name in enumerate(self.table):
            self._param_value(name, index)

    def on_request_read(self, msg) -> None:
        names = list(self.table)
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("ascii", "replace")
        if name in self.table:
            self._param_value(name, names.index(name))
        elif 0 <= msg.param_index < len(names):
            self._param_value(names[msg.param_index], msg.param_index)

    def on_set(self, msg) -> None:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("ascii", "replace")
        if name not in self.table:
            self.counters.add("param_set_unknown")
            return
        entry = self.table[name]
        limits = entry[2]
        value = float(msg.param_value)
        if limits is not None and math.isfinite(value) and limits[0] <= value <= limits[1]:
            entry[0] = value
            if name == "CRUISE_SPEED":
                self.guidance.cruise_speed_mps = value
            elif name == "GUID_TIMEOUT":
                self.guidance.setpoint_timeout_s = value
        else:
            self.counters.add("param_set_refused")
            self.out.say(f"param_{name}", SEVERITY_WARNING, f"PARAM_SET {name} refused")
        self._param_value(name, list(self.table).index(name))

"""The motor's field on ArduPilot's compass when our world is its physics (``--model JSON``).

SITL adds its motor interference ``SIM_MAG_MOT`` (mGauss per ampere, body axes) times the *physics
backend's* battery current to the body field (``Aircraft::update_mag_field_bf``: ``mag_bf +=
sitl->mag_mot.get() * battery_current``). The JSON backend of the shared binary (ArduPilot master of
2025-10-24) never sets that current: its frame has no battery key (its own start-up list, "JSON
received:", names timestamp, imu, position, attitude, velocity and nothing more; later ArduPilot reads
``"battery": {"voltage", "current"}``), and ``JSON::update`` does not call ``update_battery()``. So the
current stays 0 and the compass never sees the motor, while SYS_STATUS shows 50 A x throttle: that is
SITL's separate fallback for its battery monitor when the backend reports no voltage
(``SITL_State_Common::update_voltage_current``). See docs/notes/2026-12-06-ardupilot-json-lockstep.md,
section 9.

What the shared binary does read live is its compass's offsets: ``AP_Compass_SITL`` computes each sample
as ``inv(M) (B + noise) - SIM_MAG1_OFS`` (``M``: the soft iron of ``SIM_MAG1_DIA/ODI``). A field ``m I``
added to ``B``, as a newer SITL adds it, is therefore the same sample as ``SIM_MAG1_OFS`` lowered by
``inv(M) m I``. :class:`MotorField` does that: from the throttle ArduPilot commands in each frame it
takes SITL's own current law (50 A x |throttle|, as its battery monitor reports and its built-in boats
draw: ``Aircraft::update_battery``), and whenever the field it makes has moved by more than
``step_mgauss`` (at most once per ``min_interval_s`` of firmware time) it sets ``SIM_MAG1_OFS_X/Y/Z``
over the companion relay's link to ArduPilot's SERIAL1 when the world has one (``send``), else over its own
MAVLink link, ArduPilot's SERIAL2 (TCP ``5763 + 10 I``): SITL polls each connected TCP port three times a
loop (strace), a third of its port polling for about 30 messages an hour. The battery monitor's current and
the compass's motor field then move together, as on a boat, and ``COMPASS_MOTCT 2`` can compensate it.
"""
from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("MAVLINK20", "1")

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

__all__ = ["MotorFieldConfig", "MotorField", "sitl_current_a", "serial2_port", "FULL_THROTTLE_CURRENT_A"]

FULL_THROTTLE_CURRENT_A = 50.0     # SITL's "assume 50A at full throttle" (battery monitor and built-in models)
WORLD_SYSID = 250                  # the world's MAVLink identity on SERIAL2 (not a ground station's 255)


def sitl_current_a(throttle: float) -> float:
    """SITL's battery current (A) for a Rover's normalised throttle (-1..1).

    >>> sitl_current_a(0.8), sitl_current_a(-1.0), sitl_current_a(0.0)
    (40.0, 50.0, 0.0)
    """
    return FULL_THROTTLE_CURRENT_A * min(abs(throttle), 1.0)


def serial2_port(instance: int) -> int:
    return 5763 + 10 * instance


@dataclass(frozen=True)
class MotorFieldConfig:
    """The compass's simulated errors the field is made with: ``SIM_MAG_MOT`` (mGauss/A) and the first
    compass's ``SIM_MAG1_OFS`` (mGauss), ``_DIA`` and ``_ODI``, as ArduPilot was given them."""

    mot: tuple[float, float, float]
    ofs: tuple[float, float, float]
    dia: tuple[float, float, float] = (1.0, 1.0, 1.0)
    odi: tuple[float, float, float] = (0.0, 0.0, 0.0)
    step_mgauss: float = 1.0          # below the compass's noise (SIM_MAG_RND 2.6: 1.5 mGauss sd)
    min_interval_s: float = 1.0

    @classmethod
    def parse(cls, text: str) -> "MotorFieldConfig":
        """``MOT;OFS;DIA;ODI``, each ``x,y,z`` (the world's ``--motor-field``).

        >>> MotorFieldConfig.parse("-0.71,-0.14,0.68;-97.79,118.11,213.18;1,1,1;0,0,0").mot
        (-0.71, -0.14, 0.68)
        """
        parts = [tuple(float(v) for v in p.split(",")) for p in text.split(";")]
        if len(parts) != 4 or any(len(p) != 3 for p in parts):
            raise ValueError(f"--motor-field {text!r}: expected MOT;OFS;DIA;ODI, each x,y,z")
        return cls(*parts)

    def offsets_at(self, current_a: float) -> tuple[float, float, float]:
        """``SIM_MAG1_OFS`` that makes the sample of a field ``mot x current`` stronger.

        >>> MotorFieldConfig((-0.71, -0.14, 0.68), (10.0, 20.0, 30.0)).offsets_at(10.0)
        (17.1, 21.4, 23.2)
        """
        d, o = self.dia, self.odi
        soft = np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])
        shift = np.linalg.solve(soft, np.asarray(self.mot) * current_a)
        return tuple(round(float(v), 4) for v in np.asarray(self.ofs) - shift)


class MotorField:
    """The motor's field for ArduPilot instance ``instance``: :meth:`update` once per frame. ``send``: writes
    frames to ArduPilot over a link the world already has (False while it cannot); None: SERIAL2."""

    def __init__(self, instance: int, config: MotorFieldConfig,
                 send: Callable[[bytes], bool] | None = None) -> None:
        self.instance = instance
        self.config = config
        self._send = send
        self.sock: socket.socket | None = None
        self._mav = mavlink.MAVLink(None, srcSystem=WORLD_SYSID, srcComponent=mavlink.MAV_COMP_ID_USER1)
        self._tries = 0
        self._sent_current_a = 0.0       # the field's current as ArduPilot has it (SIM_MAG1_OFS as given)
        self._next_us = 0
        self._min_interval_us = int(config.min_interval_s * 1e6)
        norm = float(np.linalg.norm(config.mot))
        self._step_a = config.step_mgauss / norm if norm > 0.0 else float("inf")
        self.updates = 0

    def _connect(self) -> None:
        self._tries += 1
        if self._tries % 50 != 1:     # ArduPilot opens its ports after its first frames: try now and then
            return
        try:
            sock = socket.create_connection(("127.0.0.1", serial2_port(self.instance)), timeout=1.0)
        except OSError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.sock = sock

    def update(self, now_us: int, throttle: float) -> None:
        """The frame at firmware time ``now_us`` carries ``throttle``: set the offsets when due."""
        current = sitl_current_a(throttle)
        if now_us < self._next_us or abs(current - self._sent_current_a) < self._step_a:
            return
        frames = b"".join(
            mavlink.MAVLink_param_set_message(1, 1, name.encode("ascii"), value, mavlink.MAV_PARAM_TYPE_REAL32)
            .pack(self._mav) for name, value in zip(("SIM_MAG1_OFS_X", "SIM_MAG1_OFS_Y", "SIM_MAG1_OFS_Z"),
                                                    self.config.offsets_at(current)))
        if not (self._send(frames) if self._send is not None else self._send_serial2(frames)):
            return
        self._sent_current_a = current
        self._next_us = now_us + self._min_interval_us
        self.updates += 1

    def _send_serial2(self, frames: bytes) -> bool:
        if self.sock is None:
            self._connect()
            if self.sock is None:
                return False
        self._drain()
        if self.sock is None:
            return False
        try:
            self.sock.setblocking(True)
            self.sock.sendall(frames)
            self.sock.setblocking(False)
        except OSError:
            self.close()
            return False
        return True

    def _drain(self) -> None:
        """Discard what ArduPilot sent on the port (its PARAM_VALUE answers, heartbeats)."""
        try:
            while self.sock.recv(65536):
                pass
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self.close()

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = None

    def stats(self) -> dict:
        return {"motor_field_updates": self.updates}

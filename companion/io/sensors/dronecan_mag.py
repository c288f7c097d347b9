"""DroneCAN magnetometers through python-can and the ``dronecan`` package.

Messages received (all body frame, Gauss; 1 G = 100 000 nT):

* ``uavcan.equipment.ahrs.MagneticFieldStrength2`` (1002): ``sensor_id`` + float16[3];
* ``uavcan.equipment.ahrs.MagneticFieldStrength`` (1001, deprecated): float16[3], no
  sensor id -- treated as sensor 0, as ArduPilot does;
* ``dronecan.sensors.magnetometer.MagneticFieldStrengthHiRes`` (1043): float32[3].

float16 has an 11-bit significand: at 0.5 G a component is quantised to about 24 nT
(0.03 degree of declination); prefer the HiRes message where a node offers it.

The node is passive (anonymous) by default: it only listens, so it needs no node id and
sends nothing on the bus.

Two pitfalls of dronecan 1.0.27 with python-can, measured (see /work/shared/PACKAGES.md):
its python-can driver passes ``timeout * 1000`` to ``Bus.recv``, which takes seconds,
so ``Node.spin(t)`` with t > 0 blocks a thousand times too long; this source therefore
only calls ``spin(0)`` and waits in short sleeps. And python-can's ``virtual`` bus lacks
``flush_tx_buffer``, which the driver calls after every send: a sending node on a
virtual bus (tests) needs ``VirtualBus.flush_tx_buffer = lambda self: None``.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from companion.io.sensors.base import MagSample, Sample, SampleFlag, SampleKind, SensorError, SensorSource
from companion.io.sensors.quality import MagChecks, MagQualityCheck

__all__ = ["DroneCanMagConfig", "DroneCanMagSource", "GAUSS_TO_NT"]

GAUSS_TO_NT = 100_000.0
_IDLE_SLEEP_S = 0.002  # between spin(0) calls while waiting for a frame


@dataclass(frozen=True)
class DroneCanMagConfig:
    """Settings of :class:`DroneCanMagSource`.

    ``channel``: CAN interface (``can0``) or virtual channel name; ``bustype``: python-can
    interface (``socketcan`` on a board, ``virtual`` in tests); ``sensor_id``: accept only
    this sensor (None: all; legacy messages count as sensor 0); ``source_node_id``: accept
    only this sender node (None: any); ``node_id``: our node id, None for a passive
    listener; ``checks``: stuck/spike thresholds, None to disable.
    """

    channel: str = "can0"
    bustype: str = "socketcan"
    bitrate: int = 1_000_000
    sensor_id: int | None = None
    source_node_id: int | None = None
    node_id: int | None = None
    checks: MagChecks | None = field(default_factory=MagChecks)

    def __post_init__(self) -> None:
        if self.sensor_id is not None and not 0 <= self.sensor_id <= 255:
            raise ValueError(f"DroneCanMagConfig.sensor_id must be in [0, 255], got {self.sensor_id}")
        for name in ("source_node_id", "node_id"):
            value = getattr(self, name)
            if value is not None and not 1 <= value <= 127:
                raise ValueError(f"DroneCanMagConfig.{name} must be in [1, 127], got {value}")
        if self.bitrate <= 0:
            raise ValueError(f"DroneCanMagConfig.bitrate must be > 0, got {self.bitrate}")


class DroneCanMagSource(SensorSource):
    """Magnetometer readings from DroneCAN nodes as :class:`MagSample` (instance = sensor id).

    ``time_s`` is the driver's reception timestamp on the host monotonic clock.
    ``node_factory`` replaces ``dronecan.make_node`` (tests, or a shared node).
    """

    provides = frozenset({SampleKind.MAG})

    def __init__(
        self,
        config: DroneCanMagConfig | None = None,
        *,
        node_factory: Callable[..., Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        name: str | None = None,
    ) -> None:
        super().__init__()
        self.config = config or DroneCanMagConfig()
        self._node_factory = node_factory
        self._clock = clock
        self._sleep = sleep
        self._node: Any = None
        self._handles: list[Any] = []
        self._pending: list[Sample] = []
        self._checks: dict[int, MagQualityCheck] = {}
        self.name = name or f"dronecan@{self.config.bustype}:{self.config.channel}"
        self.ignored = 0  # messages filtered out by sensor or node id

    def open(self) -> None:
        if self._node is not None:
            return  # already open
        import dronecan

        factory = self._node_factory or dronecan.make_node
        cfg = self.config
        try:
            self._node = factory(cfg.channel, node_id=cfg.node_id, bustype=cfg.bustype, bitrate=cfg.bitrate)
        except Exception as err:  # python-can raises many types (CanError, OSError, ValueError...)
            raise SensorError(f"{self.name}: cannot open CAN interface {cfg.channel!r} "
                              f"({cfg.bustype}): {err}") from err
        ahrs = dronecan.uavcan.equipment.ahrs
        self._handles = [
            self._node.add_handler(ahrs.MagneticFieldStrength2, self._on_mag2),
            self._node.add_handler(ahrs.MagneticFieldStrength, self._on_mag_legacy),
            self._node.add_handler(dronecan.dronecan.sensors.magnetometer.MagneticFieldStrengthHiRes,
                                   self._on_mag2),
        ]

    def close(self) -> None:
        for handle in self._handles:
            handle.remove()
        self._handles = []
        if self._node is not None:
            try:
                self._node.close()
            except (OSError, RuntimeError):
                pass  # the interface went away; nothing left to release
        self._node = None

    def _accept(self, event: Any, sensor_id: int) -> None:
        cfg = self.config
        if (cfg.sensor_id is not None and sensor_id != cfg.sensor_id) or (
                cfg.source_node_id is not None and event.transfer.source_node_id != cfg.source_node_id):
            self.ignored += 1
            return
        ga = event.message.magnetic_field_ga
        mag = (float(ga[0]) * GAUSS_TO_NT, float(ga[1]) * GAUSS_TO_NT, float(ga[2]) * GAUSS_TO_NT)
        flags = SampleFlag.NONE
        if cfg.checks is not None:
            check = self._checks.setdefault(sensor_id, MagQualityCheck(cfg.checks))
            flags = check.check(tuple(float(c) for c in ga), mag)
        self._pending.append(MagSample(time_s=event.transfer.ts_monotonic, mag_body_nt=mag,
                                       instance=sensor_id, flags=flags))

    def _on_mag2(self, event: Any) -> None:
        self._accept(event, int(event.message.sensor_id))

    def _on_mag_legacy(self, event: Any) -> None:
        self._accept(event, 0)

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        if self._node is None:
            raise SensorError(f"{self.name}: poll() before open()")
        deadline = self._clock() + timeout_s
        while True:
            try:
                self._node.spin(0)
            except Exception as err:  # a driver error must not stop the companion
                self.stats.record_error(f"CAN receive: {err}")
            if self._pending or self._clock() >= deadline:
                break
            self._sleep(min(_IDLE_SLEEP_S, max(0.0, deadline - self._clock())))
        out, self._pending = self._pending, []
        self.stats.count(out)
        return out

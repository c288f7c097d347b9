"""``make_source(spec)``: a sensor source from a short text spec (command line, parameters).

Specs::

    i2c:/dev/i2c-1            MPU9250 + AK8963 on I2C bus 1 (also ``i2c:1``)
    ubx:/dev/ttyACM0:115200   u-blox on a serial port (baud optional, default 9600)
    dronecan:can0             DroneCAN magnetometer on SocketCAN can0
    dronecan:virtual:vbus0    ... on python-can's virtual bus (tests); any python-can bustype
    replay:logs/log171.bin?speed=fast   a DataFlash or tlog log, as fast as possible
    replay:flight.tlog?speed=1.0        ... at recorded speed
    i2c:/dev/i2c-1+ubx:/dev/ttyAMA0:9600   several at once (the paper's direct device)

``?key=value&...`` after a spec sets options (``0x69``, ``2.5``, ``true``, ``none``
are converted); keyword options to ``make_source`` override them. Options are the
fields of the source's config dataclass plus its constructor keywords (``clock``,
``sleep``, ``name``, ``bus``, ``serial_port``, ``node_factory``). For a combination,
pass options per kind: ``make_source("i2c:1+ubx:/dev/ttyS0", i2c={"address": 0x69})``.

The source is returned closed: call ``open()`` or use it in a ``with`` block.

>>> make_source("replay:flight.bin?speed=fast").speed is None
True
"""
from __future__ import annotations

import dataclasses
import re
from typing import Any

from companion.io.sensors.base import SensorSource
from companion.io.sensors.combined import CombinedSource

__all__ = ["SCHEMES", "make_source", "parse_spec"]

SCHEMES = ("i2c", "ubx", "dronecan", "replay")
_SPLIT = re.compile(r"\+(?=(?:{}):)".format("|".join(SCHEMES)))


def _coerce(text: str) -> Any:
    low = text.lower()
    if low in ("none", "null"):
        return None
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def parse_spec(spec: str) -> tuple[str, str, dict[str, Any]]:
    """``(scheme, body, query options)`` of one spec.

    >>> parse_spec("dronecan:virtual:vbus0?sensor_id=2")
    ('dronecan', 'virtual:vbus0', {'sensor_id': 2})
    """
    scheme, sep, rest = spec.partition(":")
    if not sep or scheme not in SCHEMES:
        raise ValueError(f"sensor spec {spec!r}: expected one of {', '.join(s + ':...' for s in SCHEMES)}")
    body, _, query = rest.partition("?")
    if not body:
        raise ValueError(f"sensor spec {spec!r}: nothing after {scheme + ':'!r}")
    options: dict[str, Any] = {}
    for item in filter(None, query.split("&")):
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ValueError(f"sensor spec {spec!r}: option {item!r} is not key=value")
        options[key] = _coerce(value)
    return scheme, body, options


def _split_options(config_cls: type, ctor_keys: set[str], options: dict[str, Any],
                   spec: str) -> tuple[dict[str, Any], dict[str, Any]]:
    fields = {f.name for f in dataclasses.fields(config_cls)}
    unknown = set(options) - fields - ctor_keys
    if unknown:
        raise ValueError(f"sensor spec {spec!r}: unknown option(s) {sorted(unknown)}; "
                         f"known: {sorted(fields | ctor_keys)}")
    config = {k: v for k, v in options.items() if k in fields}
    ctor = {k: v for k, v in options.items() if k in ctor_keys}
    return config, ctor


def _make_i2c(body: str, options: dict[str, Any], spec: str) -> SensorSource:
    from companion.io.sensors.mpu9250 import Mpu9250Config, Mpu9250Source

    config, ctor = _split_options(Mpu9250Config, {"bus", "clock", "sleep", "name"}, options, spec)
    bus = ctor.pop("bus", body)
    return Mpu9250Source(bus, Mpu9250Config(**config), **ctor)


def _make_ubx(body: str, options: dict[str, Any], spec: str) -> SensorSource:
    from companion.io.sensors.ublox import UbloxConfig, UbloxSource

    port, baud = body, None
    head, sep, tail = body.rpartition(":")
    if sep and tail.isdigit():
        port, baud = head, int(tail)
    config, ctor = _split_options(UbloxConfig, {"serial_port", "clock", "name"}, options, spec)
    config.pop("port", None)
    if baud is not None:
        config.setdefault("baudrate", baud)
    return UbloxSource(UbloxConfig(port=port, **config), **ctor)


def _make_dronecan(body: str, options: dict[str, Any], spec: str) -> SensorSource:
    from companion.io.sensors.dronecan_mag import DroneCanMagConfig, DroneCanMagSource

    bustype, sep, channel = body.partition(":")
    if not sep:
        bustype, channel = "socketcan", body
    config, ctor = _split_options(DroneCanMagConfig, {"node_factory", "clock", "sleep", "name"},
                                  options, spec)
    config.setdefault("bustype", bustype)
    config.setdefault("channel", channel)
    return DroneCanMagSource(DroneCanMagConfig(**config), **ctor)


def _make_replay(body: str, options: dict[str, Any], spec: str) -> SensorSource:
    from companion.io.sensors.replay import LogReplaySource

    known = {"speed", "instances", "max_batch", "clock", "sleep", "name"}
    unknown = set(options) - known
    if unknown:
        raise ValueError(f"sensor spec {spec!r}: unknown option(s) {sorted(unknown)}; known: {sorted(known)}")
    opts = dict(options)
    speed = opts.pop("speed", None)
    if isinstance(speed, str):
        if speed.lower() != "fast":
            raise ValueError(f"sensor spec {spec!r}: speed must be a number > 0 or 'fast', got {speed!r}")
        speed = None
    instances = opts.pop("instances", (0,))
    if isinstance(instances, int):
        instances = (instances,)
    elif isinstance(instances, str):
        instances = None if instances.lower() == "all" else tuple(int(i) for i in instances.split(","))
    return LogReplaySource(body, speed=None if speed is None else float(speed), instances=instances, **opts)


_BUILDERS = {"i2c": _make_i2c, "ubx": _make_ubx, "dronecan": _make_dronecan, "replay": _make_replay}


def make_source(spec: str, **options: Any) -> SensorSource:
    """A closed :class:`SensorSource` for ``spec`` (see the module docstring)."""
    parts = _SPLIT.split(spec.strip())
    if len(parts) > 1:
        schemes = [parse_spec(p)[0] for p in parts]
        unknown = set(options) - set(schemes)
        if unknown:
            raise ValueError(f"sensor spec {spec!r}: options of a combination are given per kind "
                             f"({', '.join(schemes)}=dict(...)); got {sorted(unknown)}")
        return CombinedSource([make_source(p, **options.get(s, {})) for p, s in zip(parts, schemes)])
    scheme, body, query = parse_spec(parts[0])
    try:
        return _BUILDERS[scheme](body, {**query, **options}, spec)
    except TypeError as err:  # a wrongly typed option reaching a dataclass
        raise ValueError(f"sensor spec {spec!r}: {err}") from err

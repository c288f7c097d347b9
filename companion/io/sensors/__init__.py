"""Sensor sources: one interface, interchangeable inputs for the navigation code.

Each source turns its protocol into immutable samples (:mod:`.base`), in SI units and
the body/NED frames of :mod:`companion`, with nanotesla for the magnetic field:

========================  =====================================================
``i2c:/dev/i2c-1``        MPU9250 + AK8963 over I2C (:mod:`.mpu9250`)
``ubx:/dev/ttyACM0:9600`` u-blox NAV-PVT over serial (:mod:`.ublox`)
``dronecan:can0``         DroneCAN magnetometer (:mod:`.dronecan_mag`)
``replay:log.bin``        ArduPilot DataFlash / MAVLink tlog replay (:mod:`.replay`)
========================  =====================================================

Typical use, the shape of a MAVProxy module's receive hook::

    from companion.io.sensors import make_source, StalenessMonitor

    with make_source("i2c:/dev/i2c-1+ubx:/dev/ttyAMA0:9600") as source:
        fresh = StalenessMonitor()
        while True:
            samples = source.poll(timeout_s=0.05)
            fresh.update(samples)
            ...

Hardware modules import their drivers (smbus2, pyserial, dronecan) only when a source
of that kind is built, so replay works on a machine without them.
"""
from __future__ import annotations

from companion.io.sensors.base import (
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    Sample,
    SampleFlag,
    SampleKind,
    SensorError,
    SensorSource,
    SourceStats,
    StalenessMonitor,
    StreamEnd,
)
from companion.io.sensors.combined import CombinedSource
from companion.io.sensors.factory import make_source, parse_spec

__all__ = [
    "AttitudeSample",
    "CombinedSource",
    "GpsSample",
    "ImuSample",
    "MagSample",
    "Sample",
    "SampleFlag",
    "SampleKind",
    "SensorError",
    "SensorSource",
    "SourceStats",
    "StalenessMonitor",
    "StreamEnd",
    "make_source",
    "parse_spec",
]

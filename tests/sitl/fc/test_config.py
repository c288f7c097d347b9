"""The stand-in's start-up syntax without sockets: endpoints (sitl.links) and faults (sitl.fc.config)."""
from __future__ import annotations

import math

import pytest

from sitl.links import EndpointError, parse_endpoint
from sitl.fc import parse_fault


def test_parse_endpoint_and_fault():
    assert parse_endpoint("udp:127.0.0.1:14550").kind == "udpout"
    assert parse_endpoint("udpin:0.0.0.0:14551").kind == "udpin"
    assert parse_endpoint("tcp:127.0.0.1:5760").port == 5760
    assert parse_endpoint("udp:14550").host == "127.0.0.1"
    for bad in ("serial:/dev/ttyS0", "udp:host:port", "tcp:1.2.3.4:70000", "udp"):
        with pytest.raises(EndpointError):
            parse_endpoint(bad)
    f = parse_fault("mag_spike:30:2:5000")
    assert (f.kind, f.at_s, f.duration_s, f.value) == ("mag_spike", 30.0, 2.0, 5000.0)
    assert parse_fault("gps_off:10").duration_s == math.inf
    for bad in ("nope:1", "mag_off", "mag_off:x", "mag_off:-1", "mag_off:1:0", "mag_off:1:2:nan"):
        with pytest.raises(ValueError):
            parse_fault(bad)

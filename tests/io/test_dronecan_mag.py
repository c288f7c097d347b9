"""DroneCAN magnetometer frames from a second dronecan node over python-can's virtual bus."""
from __future__ import annotations

import itertools
import time

import can.interfaces.virtual
import dronecan
import pytest

from companion.io.sensors import MagSample, SensorError, make_source
from companion.io.sensors.dronecan_mag import DroneCanMagConfig, DroneCanMagSource

# dronecan's own driver still passes python-can the deprecated 'bustype' keyword.
pytestmark = pytest.mark.filterwarnings("ignore:The 'bustype' argument is deprecated:DeprecationWarning")

_channels = itertools.count()


@pytest.fixture
def channel(monkeypatch: pytest.MonkeyPatch) -> str:
    # dronecan's python-can driver calls flush_tx_buffer() after each send, which the
    # virtual bus does not implement (see /work/shared/PACKAGES.md).
    monkeypatch.setattr(can.interfaces.virtual.VirtualBus, "flush_tx_buffer", lambda self: None,
                        raising=False)
    return f"fcmpc-test-{next(_channels)}"


@pytest.fixture
def sender(channel: str):
    nodes = []

    def make(node_id: int = 42):
        node = dronecan.make_node(channel, node_id=node_id, bustype="virtual", bitrate=1_000_000)
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.close()


def mag2(sensor_id: int, gauss: tuple[float, float, float]):
    return dronecan.uavcan.equipment.ahrs.MagneticFieldStrength2(sensor_id=sensor_id, magnetic_field_ga=list(gauss))


def collect(src: DroneCanMagSource, count: int, timeout_s: float = 3.0) -> list[MagSample]:
    got: list[MagSample] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < count and time.monotonic() < deadline:
        got += src.poll(0.05)
    return got


def test_sensor_id_filter_and_gauss_to_nanotesla(channel: str, sender) -> None:
    tx = sender()
    src = make_source(f"dronecan:virtual:{channel}?sensor_id=2")
    assert isinstance(src, DroneCanMagSource)
    with src:
        t0 = time.monotonic()
        tx.broadcast(mag2(1, (0.1, 0.1, 0.1)))
        tx.broadcast(mag2(2, (0.2314, 0.0508, -0.5313)))
        tx.broadcast(mag2(3, (0.3, 0.3, 0.3)))
        tx.broadcast(mag2(2, (0.2400, -0.0100, -0.5200)))
        got = collect(src, 2)
        time.sleep(0.05)
        got += src.poll(0.0)  # nothing else may arrive
    assert [s.instance for s in got] == [2, 2]
    # float16 on the wire: 11 significant bits, about 2.4e-4 G = 24 nT at 0.5 G.
    assert got[0].mag_body_nt == pytest.approx((23140.0, 5080.0, -53130.0), abs=15.0)
    assert got[1].mag_body_nt == pytest.approx((24000.0, -1000.0, -52000.0), abs=15.0)
    assert all(s.valid for s in got)
    assert t0 <= got[0].time_s <= time.monotonic()  # reception time, host monotonic clock
    assert src.ignored == 2


def test_all_sensors_legacy_and_hires_messages(channel: str, sender) -> None:
    tx = sender()
    src = DroneCanMagSource(DroneCanMagConfig(channel=channel, bustype="virtual"))
    with src:
        tx.broadcast(mag2(1, (0.2, 0.0, -0.5)))
        tx.broadcast(dronecan.uavcan.equipment.ahrs.MagneticFieldStrength(magnetic_field_ga=[0.25, 0.01, -0.45]))
        tx.broadcast(dronecan.dronecan.sensors.magnetometer.MagneticFieldStrengthHiRes(
            sensor_id=4, magnetic_field_ga=[0.231456, 0.050812, -0.531271]))
        got = collect(src, 3)
    assert sorted(s.instance for s in got) == [0, 1, 4]
    hires = next(s for s in got if s.instance == 4)
    # float32: the conversion itself is exact to well under a nanotesla.
    assert hires.mag_body_nt == pytest.approx((23145.6, 5081.2, -53127.1), abs=0.01)
    legacy = next(s for s in got if s.instance == 0)
    assert legacy.mag_body_nt == pytest.approx((25000.0, 1000.0, -45000.0), abs=15.0)


def test_source_node_filter(channel: str, sender) -> None:
    a, b = sender(42), sender(43)
    src = DroneCanMagSource(DroneCanMagConfig(channel=channel, bustype="virtual", source_node_id=43))
    with src:
        a.broadcast(mag2(0, (0.1, 0.0, 0.0)))
        b.broadcast(mag2(0, (0.2, 0.0, 0.0)))
        got = collect(src, 1)
        time.sleep(0.05)
        got += src.poll(0.0)
    assert len(got) == 1 and got[0].mag_body_nt[0] == pytest.approx(20000.0, abs=15.0)


def test_poll_returns_empty_after_its_timeout_without_traffic(channel: str) -> None:
    src = DroneCanMagSource(DroneCanMagConfig(channel=channel, bustype="virtual"))
    with src:
        t = time.monotonic()
        assert src.poll(0.1) == []
        assert 0.09 <= time.monotonic() - t < 0.5  # not the driver's 1000x timeout


def test_an_unknown_interface_is_a_clear_error() -> None:
    src = DroneCanMagSource(DroneCanMagConfig(channel="nosuchcan0", bustype="socketcan"))
    with pytest.raises(SensorError, match=r"cannot open CAN interface 'nosuchcan0' \(socketcan\)"):
        src.open()


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="sensor_id"):
        DroneCanMagConfig(sensor_id=300)
    with pytest.raises(ValueError, match="node_id"):
        DroneCanMagConfig(node_id=0)

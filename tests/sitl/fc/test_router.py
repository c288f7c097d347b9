"""sitl.fc.router over real sockets: malformed input, a TCP master like ArduPilot SITL, routing between links."""
from __future__ import annotations

import errno
import math
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.ports import free_port
from tests.sitl.fc.helpers import ARM, DO_SET_MODE, HOLD, SET_INTERVAL, send_velocity


def test_malformed_flood_does_not_stop_the_simulator(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    client.wait_mode(HOLD)
    sock = client.conn.port
    target = server.links[0].local_address
    rng = np.random.default_rng(3)
    good = mavlink.MAVLink(None, 1, 191)
    valid = good.command_long_encode(1, 1, SET_INTERVAL, 0, 27, 100_000, 0, 0, 0, 0, 0).pack(good)
    for k in range(400):
        kind = k % 6
        if kind == 0:
            data = rng.integers(0, 256, int(rng.integers(1, 600)), dtype=np.uint8).tobytes()
        elif kind == 1:                                     # valid frame, CRC broken
            data = valid[:-1] + bytes([valid[-1] ^ 0xFF])
        elif kind == 2:                                     # truncated frame
            data = valid[: int(rng.integers(1, len(valid) - 1))]
        elif kind == 3:                                     # unknown message id 0xABCDE
            data = bytes([0xFD, 4, 0, 0, 0, 1, 191, 0xDE, 0xBC, 0x0A, 1, 2, 3, 4, 0x12, 0x34])
        elif kind == 4:                                     # markers with absurd lengths, a MAVLink 1 header
            data = b"\xfd\xff\xff" + b"\xfe\xff" * 50
        else:                                               # many frames glued with garbage between
            data = b"\x00\xfd" + valid[:7] + b"\xfe\x09" + rng.bytes(30)
        sock.sendto(data, target)
    # NaN / out-of-range setpoints and commands
    t = client.time_ms()
    send_velocity(client, t, math.nan, 1.0)
    send_velocity(client, t, 1e6, 0.0)
    client.mav.command_long_send(1, 1, ARM, 0, math.nan, 0, 0, 0, 0, 0, 0)
    client.mav.command_long_send(1, 1, DO_SET_MODE, 0, math.nan, math.inf, 0, 0, 0, 0, 0)
    # still alive: heartbeats continue and a command after the flood is acknowledged
    t_after = client.time_ms()
    client.recv("HEARTBEAT", 5.0, lambda m: True)
    assert client.command(SET_INTERVAL, 27, 100_000).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.time_ms() > t_after
    c = server.counters
    assert c.get("rx_bad_frames", 0) > 50 and c.get("rx_garbage_bytes", 0) > 1000
    assert c.get("rx_unknown_messages", 0) >= 60
    assert c.get("rx_handler_errors", 0) == 0
    assert server.guidance.counters.get("setpoints_ignored_mode", 0) + c.get("setpoints_rejected_nan", 0) >= 1


def test_tcp_master_like_ardupilot_sitl(tmp_path):
    import threading
    from pymavlink import mavutil
    from sitl.fc import ServerConfig, SitlServer

    port = free_port()
    server = SitlServer(ServerConfig(masters=(f"tcp:127.0.0.1:{port}",), speedup=20.0, quiet=True,
                                     log_dir=str(tmp_path), init_s=0.2))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
        hb = conn.wait_heartbeat(timeout=5)
        assert hb is not None and hb.type == mavlink.MAV_TYPE_SURFACE_BOAT
        conn.mav.param_request_list_send(1, 1)
        names = set()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(names) < len(server.params):
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None:
                names.add(msg.param_id)
        assert {"SYSID_THISMAV", "GUID_TIMEOUT"} <= names
        conn.mav.command_long_send(1, 1, SET_INTERVAL, 0, 30, 50_000, 0, 0, 0, 0, 0)
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
        conn.close()
    finally:
        server.request_stop()
        thread.join(10)
    assert not thread.is_alive()


def test_routing_between_links(sitl):
    from pymavlink import mavutil

    port = free_port()
    server, client = sitl(speedup=20.0, init_s=0.2, masters=(f"tcp:127.0.0.1:{port}",))
    client.time_ms()
    gcs = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        assert gcs.wait_heartbeat(timeout=5) is not None
        # a ground station on TCP asks the companion (1/191, on UDP) for its parameters through the vehicle
        gcs.mav.param_request_list_send(1, 191)
        msg = client.recv("PARAM_REQUEST_LIST", 5.0)
        assert (msg.get_srcSystem(), msg.target_component) == (255, 191)
        # and the companion's answer goes back to the ground station
        client.mav.named_value_float_send(1234, b"FCMPC_D", -3.9)
        got = gcs.recv_match(type="NAMED_VALUE_FLOAT", blocking=True, timeout=5)
        assert got is not None and got.name == "FCMPC_D"
    finally:
        gcs.close()
    assert server.counters.get("rx_routed", 0) >= 2


def test_udpin_on_a_port_in_use_is_refused_not_shared():
    """A ``--master udpin:`` port another socket holds (pymavlink's udpin sets SO_REUSEADDR):
    EADDRINUSE, instead of a second socket that silently takes the port's datagrams."""
    from sitl.links import open_link, parse_endpoint

    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    holder.bind(("127.0.0.1", free_port()))
    try:
        with pytest.raises(OSError) as err:
            open_link(parse_endpoint(f"udpin:127.0.0.1:{holder.getsockname()[1]}"), 0)
        assert err.value.errno == errno.EADDRINUSE
    finally:
        holder.close()

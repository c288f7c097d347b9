"""tests.ports: the blocks of two xdist workers are disjoint and clear of the kernel's ephemeral
range (where every port-0 bind draws), a port is not handed out twice, a held one is skipped."""
from __future__ import annotations

import socket

from tests.ports import _ephemeral_range, free_port, port_block


def test_worker_blocks_are_disjoint_and_outside_the_ephemeral_range():
    low, high = _ephemeral_range()
    blocks = [port_block(f"gw{k}", "4") for k in range(4)]
    for k, block in enumerate(blocks):
        assert len(block) >= 1000 and (block.stop <= low or block.start > high)
        assert not any(set(block) & set(other) for other in blocks[k + 1:])
    assert port_block("gw0", "1") == port_block("", "")      # no xdist: the whole pool, as one worker


def test_free_ports_are_distinct_and_a_held_one_is_skipped():
    first = free_port()
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)     # as pymavlink's udpin
    block = port_block()
    nxt = block[(block.index(first) + 1) % len(block)]
    try:
        held.bind(("127.0.0.1", nxt))
        ports = [free_port() for _ in range(50)]
    finally:
        held.close()
    assert nxt not in ports and first not in ports and len(set(ports)) == 50
    assert all(p in block for p in ports)

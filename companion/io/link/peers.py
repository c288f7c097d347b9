"""Who is on the link: one MAVLink parser per sender address, a bounded table, and the pinned peers.

pymavlink's UDP listener feeds every datagram from every sender into one parser, remembers
every sender for ever and sends all output to each (issue 10: a 2-byte datagram ``fd ff`` from a
stranger swallowed the next ~16 genuine frames; 2,000 fake source ports raised the idle
companion from 4 % to 67 % CPU and gave a stranger all telemetry). Here:

* each sender address has its own parser (:class:`Peer`), so garbage from one sender can only
  spoil that sender's frames; over UDP a frame never spans datagrams (MAVLink's rule), so
  whatever is left unparsed at the end of a datagram is dropped and counted, and the next
  datagram starts clean;
* the table is bounded (:attr:`PeerTable.capacity`); a new sender evicts the one heard from
  longest ago, never the flight controller's or an allowed ground station's address;
* the flight controller is pinned (:class:`PeerPolicy`): given system/component ids, or the
  first autopilot heard, then fixed for the run; its frames from any other address are refused
  (an impostor) unless its own address has been silent for ``repin_wall_s`` of the time the
  companion spent listening (``listened``: a companion busy or blocked while the FC's frames
  queue behind a stranger's does not count it as the FC's silence), as a router or a restarted
  simulator with a new port; a second autopilot is reported, not followed;
* outputs go only to the flight controller's address and to the addresses of allowed ground
  stations (:meth:`PeerTable.destinations`), never to a stranger;
* datagrams from other addresses share a budget of ``STRANGER_RATE_HZ`` per wall second
  (:meth:`PeerTable.admit_datagram`); beyond it they are dropped unparsed and counted
  (:attr:`PeerTable.shed`), so a flood costs the companion a bounded share of its loop. Measured
  in-process on the soak's hostile mix (loaded 2-core machine, indicative): about 100 us per
  datagram parsed, 7.5 us per datagram shed. The soak's wall-time heartbeat failsafes (4 without
  the budget, 5 with it, over 10^6 datagrams at load average ~15) came from the machine's load,
  not from parsing: the budget does not claim to remove them.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

from companion.io.link.conventions import mavlink
from companion.io.link.transport import STREAM

__all__ = ["PEER_CAPACITY", "STRANGER_RATE_HZ", "Peer", "PeerPolicy", "PeerTable"]

PEER_CAPACITY = 32          # sender addresses tracked at once (a companion link has 1-3 genuine ones)
STRANGER_RATE_HZ = 200.0    # datagrams per wall second parsed from addresses that are neither the FC's nor a GCS's
STRANGER_BURST = 200.0
REPIN_WALL_S = 5.0          # the FC's address silent this long: its heartbeat from a new address re-pins it


@dataclass
class Peer:
    """One sender address: its parser and what it has sent."""

    address: Hashable
    parser: object
    last_wall_s: float
    last_listened_s: float = 0.0
    frames: int = 0
    bad_frames: int = 0
    bytes_in: int = 0
    systems: set[int] = field(default_factory=set)


@dataclass
class PeerPolicy:
    """The pinned flight controller and the ground stations allowed to change parameters."""

    fc_sysid: int | None = None
    fc_compid: int | None = None
    gcs_sysids: frozenset[int] = frozenset({255})
    repin_wall_s: float = REPIN_WALL_S

    def is_autopilot_heartbeat(self, msg) -> bool:
        return msg.get_type() == "HEARTBEAT" and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID

    def may_pin(self, msg) -> bool:
        """Whether ``msg`` may pin the flight controller (first autopilot heartbeat matching the ids)."""
        if not self.is_autopilot_heartbeat(msg):
            return False
        if self.fc_sysid is not None and msg.get_srcSystem() != self.fc_sysid:
            return False
        return self.fc_compid is None or msg.get_srcComponent() == self.fc_compid


class PeerTable:
    """Sender address -> :class:`Peer`, bounded, least recently heard evicted first."""

    def __init__(self, make_parser: Callable[[], object], wall: Callable[[], float],
                 capacity: int = PEER_CAPACITY, policy: PeerPolicy | None = None,
                 stranger_rate_hz: float = STRANGER_RATE_HZ, listened: Callable[[], float] | None = None) -> None:
        if capacity < 2:
            raise ValueError(f"peer table capacity {capacity} must be at least 2")
        self.make_parser = make_parser
        self.wall = wall
        self.listened = listened or wall     # the clock the FC's silence is judged on (re-pinning)
        self.capacity = capacity
        self.policy = policy or PeerPolicy()
        self.peers: OrderedDict[Hashable, Peer] = OrderedDict()
        self.fc_address: Hashable | None = None
        self.fc_ids: tuple[int, int] | None = None
        self.gcs_addresses: OrderedDict[Hashable, float] = OrderedDict()
        self.evicted = 0
        self.shed = 0
        self.impostor_frames = 0
        self.stranger_rate_hz = stranger_rate_hz
        self._burst = max(STRANGER_BURST, stranger_rate_hz) if math.isfinite(stranger_rate_hz) else math.inf
        self._tokens = self._burst
        self._tokens_wall = wall()
        self.other_autopilots: set[tuple[int, int]] = set()

    def peer(self, address: Hashable) -> Peer:
        """The peer of an address (created, evicting the stalest unprotected one if full)."""
        now = self.wall()
        peer = self.peers.get(address)
        if peer is None:
            if len(self.peers) >= self.capacity:
                self._evict()
            peer = Peer(address, self.make_parser(), now)
            self.peers[address] = peer
        else:
            self.peers.move_to_end(address)
        peer.last_wall_s = now
        peer.last_listened_s = self.listened()
        return peer

    def _evict(self) -> None:
        protected = {self.fc_address, *self.gcs_addresses}
        for address in self.peers:
            if address not in protected:
                del self.peers[address]
                self.evicted += 1
                return
        self.peers.popitem(last=False)   # pragma: no cover - capacity >= 2 and at most 1 + allowed GCS protected
        self.evicted += 1

    def admit_datagram(self, address: Hashable) -> bool:
        """False (shed, counted) for a stranger's datagram beyond the strangers' shared budget."""
        if address == self.fc_address or address == STREAM or address in self.gcs_addresses:
            return True   # a serial or TCP link has one peer: nobody else can inject there
        if not math.isfinite(self._burst):
            return True
        now = self.wall()
        self._tokens = min(self._burst, self._tokens + (now - self._tokens_wall) * self.stranger_rate_hz)
        self._tokens_wall = now
        if self._tokens < 1.0:
            self.shed += 1
            return False
        self._tokens -= 1.0
        return True

    # --- judging who sent a frame -------------------------------------------------------------
    def admit(self, address: Hashable, msg) -> bool:
        """False for a frame claiming the pinned FC's ids from an address that is not the FC's.

        Pins the flight controller on the first acceptable autopilot heartbeat; notes allowed
        ground stations' addresses (for outputs) and other autopilots (reported, not followed).
        """
        header = msg._header
        src = (header.srcSystem, header.srcComponent)
        policy = self.policy
        if self.fc_ids is None and policy.may_pin(msg):
            self.fc_ids, self.fc_address = src, address
            return True
        if src == self.fc_ids:
            if address == self.fc_address:
                return True
            fc_peer = self.peers.get(self.fc_address)
            silent = fc_peer is None or self.listened() - fc_peer.last_listened_s >= policy.repin_wall_s
            if silent and policy.is_autopilot_heartbeat(msg):
                self.fc_address = address
                return True
            self.impostor_frames += 1
            return False
        if self.fc_ids is not None and policy.is_autopilot_heartbeat(msg) and src[0] != self.fc_ids[0]:
            self.other_autopilots.add(src)
        if src[0] in policy.gcs_sysids:
            self.gcs_addresses[address] = self.wall()
            self.gcs_addresses.move_to_end(address)
            while len(self.gcs_addresses) > max(self.capacity // 4, 1):
                self.gcs_addresses.popitem(last=False)
        return True

    def destinations(self) -> list[Hashable]:
        """Addresses outputs go to: the flight controller's, then allowed ground stations'."""
        out = [self.fc_address] if self.fc_address is not None else []
        out += [a for a in self.gcs_addresses if a != self.fc_address]
        return out

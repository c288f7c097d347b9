"""MAVLink 2 signing for the companion's link: key file, persisted timestamp, what unsigned may pass.

Key
    32 bytes, kept as 64 hex characters on one line in a file only its owner may read
    (permission 0600 or stricter; anything else is refused with :class:`SigningError`). The key
    never leaves that file: not in a ``.parm``, a PARAM_VALUE, a log line or a STATUSTEXT; errors
    name the file, never its content. ``fcmpc-signing-key`` (:mod:`companion.io.link.keygen`)
    makes one from a random passphrase the way MAVProxy does (SHA-256 of the passphrase), so
    ``signing setup PASSPHRASE`` in MAVProxy programs the flight controller (SETUP_SIGNING) and
    MAVProxy's own link with the same key.

Timestamp
    Signed frames carry a timestamp in 10 us units since 2015-01-01 that receivers require to
    grow per (link id, system, component) stream; a restarted companion whose clock is behind
    its last run would be refused. :class:`TimestampStore` keeps a *reservation* in a file
    beside the key: the running link never signs beyond the stored value, and at start signs
    from the larger of the wall clock and that value, so the timestamp never goes back across
    restarts (power loss included), whatever the board's clock says.

What unsigned (or badly signed) frames may do
    Refused whatever their sender: PARAM_SET, PARAM_EXT_SET, every COMMAND_* and SET_* message
    and SETUP_SIGNING (:data:`SIGNED_ONLY_IDS`), counted per message name. Telemetry may arrive
    unsigned (a flight controller on a trusted serial port that does not sign) unless
    ``require_all`` is set. A frame whose signature is *wrong* is refused whatever its type.
    ArduPilot's own rule (``GCS_Signing.cpp`` accept_unsigned_callback) is stricter on a signing
    vehicle: it accepts unsigned only RADIO_STATUS and RADIO (and anything on channel 0, the
    USB port) -- hence the companion signs everything it sends (``sign_outgoing``). MAVProxy
    accepts unsigned only RADIO and RADIO_STATUS unless ``set allow_unsigned 1``.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import stat
import struct
import tempfile
import time
import types
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from companion.io.link.conventions import mavlink

__all__ = [
    "KEY_BYTES",
    "SIGNED_ONLY_IDS",
    "Signing",
    "SigningError",
    "TimestampStore",
    "check_signature",
    "passphrase_key",
    "read_key_file",
    "signing_timestamp",
    "write_key_file",
]

KEY_BYTES = 32
EPOCH_2015_UNIX_S = 1420070400
UNITS_PER_S = 100_000                 # signing timestamp unit: 10 us
RESERVE_S = 60.0                      # the stored reservation runs this far ahead of what is signed


def _signed_only_ids() -> frozenset[int]:
    names = {"PARAM_SET", "PARAM_EXT_SET", "SETUP_SIGNING"}
    ids = set()
    for msg_id, cls in mavlink.mavlink_map.items():
        name = cls.msgname
        if name in names or name.startswith(("COMMAND_", "SET_")):
            ids.add(msg_id)
    return frozenset(ids)


SIGNED_ONLY_IDS: frozenset[int] = _signed_only_ids()


def check_signature(parser, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's signature check with the order fixed: the signature first, then the timestamp.

    pymavlink 2.4.50 records a stream's timestamp *before* comparing the signature, so one forged
    frame with a large timestamp and the ids of a ground station makes every later genuine frame of
    that stream "old" (measured: a wrong-key PARAM_SET locked the real GCS out). Here only a frame
    signed with the key moves a stream's timestamp; a replay (timestamp not above the stream's
    last) or a new stream more than a minute behind our own timestamp is refused as before.
    """
    sig = parser.signing
    digest = hashlib.sha256(sig.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        return False
    low, high = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
    timestamp = low + (high << 32)
    stream = (msgbuf[-13], src_system, src_component)
    last = sig.stream_timestamps.get(stream)
    if (last is not None and timestamp <= last) or (last is None and timestamp + 60 * UNITS_PER_S < sig.timestamp):
        return False
    sig.stream_timestamps[stream] = timestamp
    sig.timestamp = max(sig.timestamp, timestamp)
    return True


class SigningError(ValueError):
    """A key file that cannot be used (missing, readable by others, not 32 bytes of hex)."""


def passphrase_key(passphrase: str) -> bytes:
    """The 32-byte key MAVProxy's ``signing setup PASSPHRASE`` derives (SHA-256 of the ASCII text).

    >>> passphrase_key("fcmpc").hex()[:16]
    '32df8e1c6c259a1b'
    """
    return hashlib.sha256(passphrase.encode("ascii")).digest()


def write_key_file(path: str | os.PathLike, key: bytes, overwrite: bool = False) -> Path:
    """Create the key file with permission 0600 (never world- or group-readable, even for a moment)."""
    if len(key) != KEY_BYTES:
        raise SigningError(f"a signing key is {KEY_BYTES} bytes, not {len(key)}")
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL)
    try:
        fd = os.open(target, flags, 0o600)
    except FileExistsError:
        raise SigningError(f"{target}: exists (give --force to replace it)") from None
    with os.fdopen(fd, "w", encoding="ascii") as handle:
        os.fchmod(handle.fileno(), 0o600)
        handle.write(key.hex() + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    return target


def read_key_file(path: str | os.PathLike) -> bytes:
    """The key of a key file; :class:`SigningError` naming the file (never its content)."""
    target = Path(path)
    try:
        mode = target.stat().st_mode
        text = target.read_text(encoding="ascii", errors="replace").strip()
    except OSError as err:
        raise SigningError(f"signing key {target}: {err.strerror or err}") from None
    if not stat.S_ISREG(mode):
        raise SigningError(f"signing key {target}: not a regular file")
    if mode & 0o077:
        raise SigningError(f"signing key {target}: permission {stat.S_IMODE(mode):04o} lets others read it; "
                           f"chmod 600 {target}")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise SigningError(f"signing key {target}: expected {2 * KEY_BYTES} hex characters on one line")
    return key


def signing_timestamp(unix_s: float) -> int:
    """A signing timestamp (10 us units since 2015-01-01) of a UNIX time."""
    return int((max(unix_s, EPOCH_2015_UNIX_S) - EPOCH_2015_UNIX_S) * UNITS_PER_S)


class TimestampStore:
    """A signing-timestamp reservation in a small file, written atomically (module docstring)."""

    def __init__(self, path: str | os.PathLike, reserve_s: float = RESERVE_S) -> None:
        self.path = Path(path)
        self.reserve = int(reserve_s * UNITS_PER_S)
        self.reserved = self._load()
        self.saves = 0

    def _load(self) -> int:
        try:
            return max(int(self.path.read_text(encoding="ascii").strip() or 0), 0)
        except (OSError, ValueError):
            return 0   # missing or torn: the wall clock alone (a torn write cannot happen: rename)

    def start(self, unix_s: float) -> int:
        """The first timestamp to sign with: never below the stored reservation."""
        first = max(signing_timestamp(unix_s), self.reserved + 1)
        self.ensure(first)
        return first

    def ensure(self, timestamp: int) -> None:
        """Store a new reservation before ``timestamp`` could pass the stored one."""
        if timestamp + self.reserve // 2 < self.reserved:
            return
        value = timestamp + self.reserve
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w", encoding="ascii") as handle:
                handle.write(f"{value}\n")
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        self.reserved = value
        self.saves += 1


@dataclass
class Signing:
    """Signing of one link: the key, our link id, the stored timestamp, and the counts of refusals."""

    key: bytes
    link_id: int = 0
    store: TimestampStore | None = None
    require_all: bool = False
    unix_clock: Callable[[], float] = time.time
    refused: Counter = field(default_factory=Counter)     # message name -> unsigned frames refused
    bad_signatures: int = 0
    unsigned_accepted: int = 0
    streams: dict = field(default_factory=dict)           # (link id, sysid, compid) -> last timestamp, shared

    def __post_init__(self) -> None:
        if len(self.key) != KEY_BYTES:
            raise SigningError(f"a signing key is {KEY_BYTES} bytes, not {len(self.key)}")
        if not 0 <= self.link_id <= 255:
            raise SigningError(f"signing link id {self.link_id} not in 0..255")

    @classmethod
    def from_file(cls, path: str | os.PathLike, link_id: int = 0, require_all: bool = False) -> Signing:
        key = read_key_file(path)
        store = TimestampStore(Path(path).with_name(Path(path).name + ".timestamp"))
        return cls(key, link_id, store, require_all)

    def setup_encoder(self, mav) -> None:
        """Sign everything ``mav`` sends, from a timestamp that never goes back."""
        sig = mav.signing
        sig.secret_key, sig.link_id, sig.sign_outgoing = self.key, self.link_id, True
        now = self.unix_clock()
        sig.timestamp = self.store.start(now) if self.store is not None else signing_timestamp(now)
        sig.stream_timestamps = self.streams

    def setup_parser(self, parser) -> None:
        sig = parser.signing
        sig.secret_key, sig.link_id, sig.sign_outgoing = self.key, self.link_id, False
        sig.allow_unsigned_callback = self._accept_unsigned
        sig.stream_timestamps = self.streams    # one replay window for every sender address
        parser._fcmpc_badsig = 0
        parser.check_signature = types.MethodType(check_signature, parser)

    def _accept_unsigned(self, parser, msg_id: int) -> bool:
        """pymavlink's callback for a frame without a valid signature: refuse or let pass."""
        if parser.signing.badsig_count != parser._fcmpc_badsig:   # it carried a signature, a wrong one
            parser._fcmpc_badsig = parser.signing.badsig_count
            self.bad_signatures += 1
            return False
        if self.require_all or msg_id in SIGNED_ONLY_IDS:
            cls = mavlink.mavlink_map.get(msg_id)
            self.refused[cls.msgname if cls is not None else str(msg_id)] += 1
            return False
        self.unsigned_accepted += 1
        return True

    def before_parse(self, parser, mav) -> None:
        """Give a parser the link's current timestamp (new streams may lag it by at most 1 min)."""
        parser.signing.timestamp = mav.signing.timestamp

    def after_parse(self, parser, mav) -> None:
        mav.signing.timestamp = max(mav.signing.timestamp, parser.signing.timestamp)

    def tick(self, mav) -> None:
        """Periodic: keep up with the wall clock and renew the stored reservation ahead of use."""
        sig = mav.signing
        sig.timestamp = max(sig.timestamp, signing_timestamp(self.unix_clock()))
        if self.store is not None:
            self.store.ensure(sig.timestamp)

    @property
    def refused_total(self) -> int:
        return sum(self.refused.values()) + self.bad_signatures

"""A datagram's MAVLink 2 frames decoded with pymavlink's own tables, without its byte-at-a-time parser.

pymavlink's ``MAVLink.parse_buffer`` calls ``parse_char`` once per frame, each call slicing
its buffer several times, building a CRC object, reordering fields in a Python loop and
constructing the message through its ``__init__``: about 11 us a frame on the companion's
machine, as long as everything else the companion does with the frame
(docs/notes/2026-12-06-capacity.md). :func:`parse_datagram` takes the common case -- the
datagram is whole, unsigned MAVLink 2 frames of ids the dialect knows, each with a good CRC --
and decodes each frame with what pymavlink generated for its id: ``crc_extra``, the ``unpacker``
struct, the field ``orders`` and the message class, producing the *same* message objects
(``tests/companion/test_fastparse.py`` compares them with pymavlink's, attribute by attribute,
on valid, fuzzed and garbage bytes). At the first byte that is not such a frame -- garbage, a
bad CRC, a signed or MAVLink 1 frame, an unknown id, a message with array fields, a frame cut
off at the end -- the rest of the datagram goes to pymavlink's own parser, exactly as before,
so every malformed-input rule (``BAD_DATA``, robust parsing, signing callbacks) is pymavlink's.
With a signing key on the parser, every frame goes through pymavlink (each needs its signature
checked there).
"""
from __future__ import annotations

import struct
from operator import itemgetter

from companion.io.link.conventions import mavlink

__all__ = ["parse_datagram", "fast_decodable"]

_MARKER_V2 = mavlink.PROTOCOL_MARKER_V2
_HEADER = struct.Struct("<BBBBBBBHB")      # magic, len, incompat, compat, seq, sysid, compid, id low, id high
_CRC = struct.Struct("<H")
_mcrf4xx = getattr(mavlink, "mcrf4xx", None)   # fastcrc's MCRF4XX (pymavlink's x25crc uses it when installed)
_new = object.__new__
_Header = mavlink.MAVLink_header


class _Spec:
    """What decoding one message id needs, taken from pymavlink's generated class."""

    __slots__ = ("cls", "extra", "size", "unpack", "order", "names", "strings", "plain", "template")

    def __init__(self, cls) -> None:
        self.cls = cls
        self.extra = bytes([cls.crc_extra])
        self.size = cls.unpacker.size
        self.unpack = cls.unpacker.unpack
        self.order = itemgetter(*cls.orders) if len(cls.orders) > 1 else (lambda t, _i=cls.orders[0]: (t[_i],))
        self.names = tuple(cls.fieldnames)
        self.strings = tuple(i for i, kind in enumerate(cls.fieldtypes) if kind.startswith("char"))
        self.plain = _plain(cls)
        # the attributes pymavlink's constructor gives every message of the class
        self.template = {"_fieldnames": cls.fieldnames, "_type": cls.msgname, "_signed": False, "_link_id": None,
                         "_instances": None, "_instance_field": cls.instance_field,
                         "_instance_offset": cls.instance_offset}


_STANDARD = frozenset(("_header", "_payload", "_msgbuf", "_crc", "_fieldnames", "_type", "_signed", "_link_id",
                       "_instances", "_instance_field", "_instance_offset"))


def _plain(cls) -> bool:
    """Whether ``cls.__init__`` only stores its fields (STATUSTEXT's also keeps ``_text_raw`` and
    decodes the text: such classes are built through their constructor)."""
    values = [b"x" if kind.startswith("char") else 0 for kind in cls.fieldtypes]
    try:
        state = vars(cls(*values))
    except Exception:  # noqa: BLE001 - a constructor that wants other values: built through it
        return False
    return set(state) == _STANDARD | set(cls.fieldnames) and [state[n] for n in cls.fieldnames] == values


def fast_decodable(cls) -> bool:
    """Whether messages of ``cls`` decode here (no array fields: pymavlink reorders those apart)."""
    return bool(cls.orders) and sum(cls.lengths) == len(cls.lengths)


_SPECS: dict[int, _Spec] = {msg_id: _Spec(cls) for msg_id, cls in mavlink.mavlink_map.items() if fast_decodable(cls)}


def _crc(body: bytes, extra: bytes) -> int:
    if _mcrf4xx is not None:
        return _mcrf4xx(extra, _mcrf4xx(body, 0xFFFF))
    crc = mavlink.x25crc(body)
    crc.accumulate(extra)
    return crc.crc


def _message(spec: _Spec, frame: bytearray, plen: int, compat: int, seq: int, sysid: int, compid: int,
             msg_id: int, crc: int):
    """The message pymavlink's ``MAVLink.decode`` builds from an unsigned MAVLink 2 ``frame`` (the
    frame's own bytearray becomes the message's ``_msgbuf``)."""
    payload = frame[10:10 + plen]
    size = spec.size
    if plen < size:
        payload += bytes(size - plen)          # MAVLink 2 trims trailing zeros
    elif plen > size:
        payload = payload[:size]
    values = spec.order(spec.unpack(payload))
    if spec.strings:
        values = list(values)
        for i in spec.strings:
            values[i] = values[i].rstrip(b"\x00")
    header = _new(_Header)   # MAVLink_header's attributes, in its constructor's order
    header.__dict__ = {"mlen": plen, "seq": seq, "srcSystem": sysid, "srcComponent": compid, "msgId": msg_id,
                       "incompat_flags": 0, "compat_flags": compat}
    if not spec.plain:
        msg = spec.cls(*values)
        msg._header, msg._payload, msg._msgbuf, msg._crc = header, frame[6:-2], frame, crc
        return msg
    msg = _new(spec.cls)
    state = spec.template.copy()
    state.update(zip(spec.names, values))
    state["_header"], state["_payload"], state["_msgbuf"], state["_crc"] = header, frame[6:-2], frame, crc
    msg.__dict__ = state
    return msg


def parse_datagram(parser, data: bytes) -> list:
    """The messages in ``data`` as ``parser.parse_buffer(data)`` returns them (an empty list for
    none), ``parser`` being a pymavlink ``MAVLink`` whose buffer may hold the start of a frame
    (a byte stream): those bytes are taken back and parsed with ``data``."""
    if parser.signing.secret_key is not None or mavlink.MAVLINK_IGNORE_CRC or parser.callback is not None:
        return parser.parse_buffer(data) or []
    fresh = len(data)
    if parser.buf_len():                       # a stream: the start of a frame is waiting
        data = parser.buf[parser.buf_index:] + data
        parser.buf, parser.buf_index = bytearray(), 0
        parser.expected_length = mavlink.HEADER_LEN_V1 + 2
    else:
        data = bytearray(data)                 # each frame's slice is its message's _msgbuf
    out = []
    specs, header, crc_of, message = _SPECS, _HEADER.unpack_from, _CRC.unpack_from, _message
    n, i = len(data), 0
    while i + 12 <= n and data[i] == _MARKER_V2:
        magic, plen, incompat, compat, seq, sysid, compid, id_low, id_high = header(data, i)
        end = i + 12 + plen
        spec = specs.get(id_low | (id_high << 16))
        if incompat or end > n or spec is None:
            break
        crc = crc_of(data, end - 2)[0]
        if crc != _crc(data[i + 1:end - 2], spec.extra):
            break
        out.append(message(spec, data[i:end], plen, compat, seq, sysid, compid, id_low | (id_high << 16), crc))
        i = end
    parser.total_bytes_received += fresh - (n - i)   # parse_buffer counts the rest
    parser.total_packets_received += len(out)
    if i < n:
        out += parser.parse_buffer(bytes(data[i:])) or []
    return out

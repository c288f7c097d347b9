"""``--http``'s address: ``ADDRESS:PORT``, ``[IPv6]:PORT``, or a port alone on loopback."""
from __future__ import annotations

__all__ = ["LOOPBACK", "parse_http_address"]

LOOPBACK = "127.0.0.1"


def parse_http_address(text: str) -> tuple[str, int]:
    """``--http``'s ``ADDRESS:PORT``, ``[IPv6]:PORT`` or ``PORT`` alone (loopback).

    >>> parse_http_address("8080"), parse_http_address("0.0.0.0:80"), parse_http_address("[::1]:8080")
    (('127.0.0.1', 8080), ('0.0.0.0', 80), ('::1', 8080))
    """
    host, sep, port_text = text.strip().rpartition(":")
    if not sep:
        host = LOOPBACK
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"--http {text!r}: expected ADDRESS:PORT or PORT, the port 1..65535")
    return host, int(port_text)

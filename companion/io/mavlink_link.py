"""Former home of the MAVLink edge, now the package :mod:`companion.io.link`; kept so existing
imports (``from companion.io.mavlink_link import MavlinkLink, mavlink``) keep working."""
from __future__ import annotations

from companion.io.link import *
from companion.io.link import __all__  # noqa: F401

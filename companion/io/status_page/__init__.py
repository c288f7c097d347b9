"""The status page on the companion board (``fcmpc-companion --http ADDRESS:PORT``), read-only.

:mod:`.snapshot` is what the companion hands the page once in a while (a frozen record, never
the companion's own objects); :mod:`.plot` draws the estimate, its 95 % ellipse, the
destination and the track (an SVG string, no map tiles); :mod:`.page` writes the HTML;
:mod:`.server` serves it, the snapshot as JSON and the records folder's files, on its own
thread with tornado. User guide: docs/status-page.md.
"""
from __future__ import annotations

from companion.io.status_page.snapshot import SensorHealth, StatusSnapshot

__all__ = ["SensorHealth", "StatusSnapshot"]

"""The status page's HTML: one page from a snapshot, the track and the records' list.

No script, no external resource (the Content-Security-Policy the server sends forbids both):
the page reloads itself every :data:`REFRESH_S` seconds. Every text that comes from outside
this module (STATUSTEXTs, mode names, file names) is escaped.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from html import escape
from urllib.parse import quote

from companion.io.status_page.plot import ellipse_95
from companion.io.status_page.snapshot import StatusSnapshot

__all__ = ["REFRESH_S", "RecordFile", "render_page"]

REFRESH_S = 5


@dataclass(frozen=True)
class RecordFile:
    """A file of the records folder, as listed."""

    name: str
    size_bytes: int
    mtime_s: float          # UNIX time


def _num(value: float, fmt: str, unit: str = "") -> str:
    return f"{value:{fmt}}{unit}" if math.isfinite(value) else "&ndash;"


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return ""   # pragma: no cover


def _rows(pairs) -> str:
    return "".join(f"<tr><th>{escape(k)}</th><td>{v}</td></tr>" for k, v in pairs)


STYLE = """
body{font-family:sans-serif;margin:12px;color:#222}h1{font-size:20px;margin:0 0 6px}
h2{font-size:15px;margin:14px 0 4px}.wrap{display:flex;flex-wrap:wrap;gap:18px}
table{border-collapse:collapse;font-size:13px}th{text-align:left;padding:1px 10px 1px 0;font-weight:normal;color:#555}
td{padding:1px 8px 1px 0}.bad{color:#b00;font-weight:bold}.ok{color:#060}
.banner{background:#b00;color:white;padding:6px;margin:6px 0}pre{font-size:12px;margin:0;white-space:pre-wrap}
"""


def render_page(snap: StatusSnapshot | None, plots: str, records: list[RecordFile]) -> str:
    """The whole page around ``plots`` (SVG, :mod:`.plot`); ``snap`` None before the companion
    handed its first snapshot."""
    head = (f'<!DOCTYPE html><html><head><meta charset="utf-8"><meta http-equiv="refresh" content="{REFRESH_S}">'
            f'<title>fcmpc companion</title><style>{STYLE}</style></head><body>')
    if snap is None:
        return head + "<h1>fcmpc companion</h1><p>starting: no state yet</p></body></html>"
    phase = f" / {escape(snap.phase)}" if snap.phase else ""
    title = f"<h1>fcmpc companion: {escape(snap.state)}{phase}, mission {snap.mission} step {snap.step}</h1>"
    when = (f"<div>message time {_num(snap.msg_time_s, '.1f', ' s')} &middot; taken "
            f"{escape(time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime(snap.wall_time_s)))}</div>")
    banner = f'<div class="banner">FAILSAFE: {escape("; ".join(snap.reasons))}</div>' if snap.failsafe else ""
    ellipse = ellipse_95(snap.est_cov_en_m2, snap.est_sigma_m)
    axes = f"{ellipse.major_m:.0f} m &times; {ellipse.minor_m:.0f} m" if ellipse is not None else "&ndash;"
    estimate = _rows((
        ("estimate", f"{_num(snap.est_lat_deg, '.6f')}, {_num(snap.est_lon_deg, '.6f')}"),
        ("1-sigma (per axis)", _num(snap.est_sigma_m, ".0f", " m")), ("95 % ellipse (semi-axes)", axes),
        ("geomagnetic fix", f"{_num(snap.fix_lat_deg, '.6f')}, {_num(snap.fix_lon_deg, '.6f')}"),
        ("destination", f"{_num(snap.dest_lat_deg, '.6f')}, {_num(snap.dest_lon_deg, '.6f')}"),
        ("remaining (estimated)", _num(snap.remaining_m / 1000.0, ".2f", " km")),
        ("command", f"{_num(snap.course_deg, '.1f', '&deg;')} at {_num(snap.speed_mps, '.2f', ' m/s')}"),
        ("restarts", str(snap.restarts))))
    fc = _rows((("flight controller", f"{escape(snap.fc_autopilot or 'not heard yet')} sysid {snap.fc_sysid}"),
                ("mode", f"{escape(snap.fc_mode)}, {'armed' if snap.fc_armed else 'disarmed'}")))
    health = "".join(
        f"<tr><th>{escape(s.name)}</th><td class=\"{'ok' if s.ok else 'bad'}\">{'ok' if s.ok else 'STALE'}</td>"
        f"<td>{_num(s.age_s, '.1f', ' s')} old" + (f" (limit {s.limit_s:g} s)" if math.isfinite(s.limit_s) else "")
        + f"</td><td>{escape(s.detail)}</td></tr>" for s in snap.sensors)
    link = _rows((name, str(value)) for name, value in snap.link)
    texts = escape("\n".join(reversed(snap.statustexts))) or "(none yet)"
    fc_texts = escape("\n".join(reversed(snap.fc_statustexts))) or "(none heard)"
    files = "".join(f'<tr><td><a href="/records/{quote(f.name)}">{escape(f.name)}</a></td>'
                    f"<td>{_size(f.size_bytes)}</td>"
                    f"<td>{escape(time.strftime('%H:%M:%S', time.gmtime(f.mtime_s)))}</td></tr>" for f in records)
    return (head + title + when + banner + '<div class="wrap"><div>' + plots + "</div><div>"
            + f"<h2>Estimate</h2><table>{estimate}</table><h2>Vehicle</h2><table>{fc}</table>"
            + f"<h2>Sensor and link health</h2><table>{health}</table><table>{link}</table>"
            + f'<h2>Records</h2><table>{files or "<tr><td>(none)</td></tr>"}</table>'
            + '<p><a href="/state.json">state.json</a> &middot; <a href="/records/">records as JSON</a></p>'
            + f"</div></div><h2>Last STATUSTEXTs, newest first: the companion's</h2><pre>{texts}</pre>"
            + f"<h2>... and the flight controller's</h2><pre>{fc_texts}</pre></body></html>")

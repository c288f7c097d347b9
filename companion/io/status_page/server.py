"""The status page's HTTP server: tornado on a thread of its own beside the companion's loop.

Read-only by construction: the handlers answer GET and HEAD only (every other method 405, with
``Allow: GET, HEAD``), and none of them reaches the companion: they read the last
:class:`~companion.io.status_page.snapshot.StatusSnapshot` handed to :meth:`StatusServer.publish`
and the records folder. Nothing the server receives changes either.

Routes
    ``/``               the page (:mod:`.page`), reloading itself every few seconds
    ``/state.json``     the snapshot as JSON (``null`` before the first)
    ``/plot.svg``       the mission's plot alone (:mod:`.plot`); ``?close_up=1`` the close-up
    ``/records/``       the records folder's files as JSON (name, size, mtime)
    ``/records/NAME``   one of them, as a download

The records folder
    Only what the listing shows is served: regular files directly in the folder, not hidden
    (a leading dot: the companion's temporaries), not symbolic links (where they point is not
    the folder). Everything else in the folder is served to whoever reaches the page: no
    secret belongs there (the systemd unit keeps the signing key in /etc/fcmpc; its UMask 0077
    makes every record mode 0600, so file modes cannot tell a record from a secret). A
    requested name is served only if it is one of those names, exactly, after URL decoding, so
    ``..``, encoded dots, absolute paths and sub-folders find nothing; the file is then opened
    relative to the folder with ``O_NOFOLLOW`` (a file swapped for a link between the listing
    and the opening is refused). A file still being written (``companion.tlog``,
    ``steps.csv``) is sent up to the size it had when opened. tornado's own StaticFileHandler
    is not used for this: it hashes a whole file for its ETag once and keeps the hash, so a
    growing tlog would be answered ``304 Not Modified`` with an old hash, and it reads a file
    to its end past the Content-Length it announced.

Limits
    Request line and headers :data:`MAX_HEADER_BYTES` (more: the connection is closed), a body
    :data:`MAX_BODY_BYTES` (more: 400 and closed; no handler reads one), a connection idle for
    :data:`IDLE_TIMEOUT_S` is closed. Malformed requests are tornado's to refuse (400, closed).
    At most :data:`MAX_CONNECTIONS` connections are open at once; one more is closed as soon
    as it is accepted: the server shares the companion's process, and a flood of idle
    connections must not take the file descriptors its link and records need.

Beside the companion
    The server runs its own asyncio event loop on a daemon thread. The sockets are bound when
    the server is built (a port in use fails the start, not a later moment); :meth:`start` starts
    the thread; :meth:`stop` ends it. The work per request is small (the page is a few kB of
    text), and the companion's loop never waits on it: :meth:`publish` swaps a reference.
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import stat
import threading
from pathlib import Path
from urllib.parse import quote

from tornado import web
from tornado.httpserver import HTTPServer
from tornado.httputil import responses
from tornado.iostream import StreamClosedError
from tornado.netutil import bind_sockets

from companion.io.records import parse_steps_csv
from companion.io.status_page.page import RecordFile, render_page
from companion.io.status_page.plot import Track, plot_svg
from companion.io.status_page.snapshot import StatusSnapshot, json_ready

__all__ = ["CHUNK_BYTES", "IDLE_TIMEOUT_S", "MAX_BODY_BYTES", "MAX_CONNECTIONS", "MAX_HEADER_BYTES", "StatusServer",
           "TrackReader", "list_records"]

MAX_HEADER_BYTES = 16 * 1024
MAX_CONNECTIONS = 64
MAX_BODY_BYTES = 4 * 1024
IDLE_TIMEOUT_S = 30.0
CHUNK_BYTES = 64 * 1024
STEPS_FILE = "steps.csv"


def list_records(folder: Path) -> list[RecordFile]:
    """The files of the records folder that may be served (see the module docstring), by name."""
    out = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return []
    for entry in entries:
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not entry.name.startswith(".") and stat.S_ISREG(st.st_mode):
            out.append(RecordFile(entry.name, st.st_size, st.st_mtime))
    return sorted(out, key=lambda f: f.name)


class TrackReader:
    """The steps' estimates and fixes from the records' ``steps.csv`` (rows of ``event`` step),
    read on from where the last call stopped, complete lines only (the companion may be writing
    the last one): a mission of thousands of steps is parsed once, a step at a time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._restart(0)

    def _restart(self, inode: int) -> None:
        self.inode, self.offset, self.header = inode, 0, b""
        self.columns: dict[str, list[float]] = {name: [] for name in _TRACK_COLUMNS}

    def read(self) -> Track:
        try:
            with open(self.path, "rb") as handle:
                st = os.fstat(handle.fileno())
                if st.st_ino != self.inode or st.st_size < self.offset:   # another file: start again
                    self._restart(st.st_ino)
                handle.seek(self.offset)
                new = handle.read()
        except OSError:
            return Track()
        complete = new[:new.rfind(b"\n") + 1]
        if complete:
            self.offset += len(complete)
            if not self.header:
                self.header, _, complete = complete.partition(b"\n")
            rows = parse_steps_csv((self.header + b"\n" + complete).decode("utf-8", errors="replace"))
            for row in rows:
                if row.get("event") == "step":
                    for name, values in self.columns.items():
                        value = row.get(name)
                        values.append(value if isinstance(value, float) else math.nan)
        return Track(*(tuple(self.columns[name]) for name in _TRACK_COLUMNS))


_TRACK_COLUMNS = ("est_lat_deg", "est_lon_deg", "fix_lat_deg", "fix_lon_deg")   # Track's fields, in order


class StatusServer:
    """Serves the status page on ``(address, port)`` from ``records_dir`` and the last snapshot."""

    def __init__(self, address: str, port: int, records_dir: Path) -> None:
        self.records_dir = Path(records_dir).resolve()
        self.address, self.port = address, port
        self.sockets = bind_sockets(port, address=address)   # OSError: in use, no such address
        self._snapshot: StatusSnapshot | None = None
        self._tracks = TrackReader(self.records_dir / STEPS_FILE)
        self._plots: tuple[tuple, str] = ((), "")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._serve()), name="status-page", daemon=True)

    @property
    def url(self) -> str:
        host = f"[{self.address}]" if ":" in self.address else self.address
        return f"http://{host}:{self.port}/"

    # ------------------------------------------------------------------ the companion's side
    def publish(self, snapshot: StatusSnapshot) -> None:
        """Hand the page a new snapshot (the companion's loop; a reference swap, never waits)."""
        self._snapshot = snapshot

    def start(self) -> None:
        self._thread.start()
        self._ready.wait(timeout=10.0)

    def stop(self) -> None:
        if self._loop is not None and self._stopping is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)
            self._thread.join(timeout=5.0)
        else:
            for sock in self.sockets:
                sock.close()

    # ------------------------------------------------------------------ the page's side
    @property
    def snapshot(self) -> StatusSnapshot | None:
        return self._snapshot

    def plots(self, snap: StatusSnapshot, close_up: bool | None = None) -> str:
        """The mission's plot and the close-up (``close_up`` None), or one of them; drawn again
        only when the estimate or the track changed (once a step, not once a request)."""
        track = self._tracks.read()
        key = (snap.est_lat_deg, snap.est_lon_deg, snap.est_sigma_m, snap.est_cov_en_m2, snap.start_lat_deg,
               snap.start_lon_deg, snap.dest_lat_deg, snap.dest_lon_deg, len(track.est_lat_deg), close_up)
        if key != self._plots[0]:
            which = (False, True) if close_up is None else (close_up,)
            svg = "".join(plot_svg(snap, track, close_up=c) for c in which)
            self._plots = (key, svg)
        return self._plots[1]

    def records(self) -> list[RecordFile]:
        return list_records(self.records_dir)

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        server = _BoundedHTTPServer(_application(self), max_header_size=MAX_HEADER_BYTES, max_body_size=MAX_BODY_BYTES,
                            idle_connection_timeout=IDLE_TIMEOUT_S, body_timeout=IDLE_TIMEOUT_S, xheaders=False)
        server.add_sockets(self.sockets)
        self._ready.set()
        await self._stopping.wait()
        server.stop()
        await server.close_all_connections()


class _BoundedHTTPServer(HTTPServer):
    """tornado's HTTPServer refusing connections beyond MAX_CONNECTIONS (closed when accepted)."""

    def handle_stream(self, stream, address) -> None:
        if len(self._connections) >= MAX_CONNECTIONS:   # HTTPServer's own set of open connections
            stream.close()
            return
        super().handle_stream(stream, address)


def _application(status: StatusServer):
    """The tornado application: the routes of the module docstring, nothing else (404)."""
    class Base(web.RequestHandler):
        SUPPORTED_METHODS = ("GET", "HEAD")   # anything else: 405 before a handler runs

        def set_default_headers(self) -> None:
            self.set_header("Allow", "GET, HEAD")
            self.set_header("Cache-Control", "no-store")
            self.set_header("X-Content-Type-Options", "nosniff")
            self.set_header("X-Frame-Options", "DENY")
            self.set_header("Referrer-Policy", "no-referrer")
            self.set_header("Content-Security-Policy", "default-src 'none'; style-src 'unsafe-inline'; img-src 'self'")

        def write_error(self, status_code: int, **kwargs) -> None:   # no traceback, no page of ours
            self.set_header("Content-Type", "text/plain; charset=utf-8")
            self.finish(f"{status_code} {responses.get(status_code, 'Error')}\n")

        def head(self, *args) -> None:
            return self.get(*args)

    class Page(Base):
        def get(self) -> None:
            self.set_header("Content-Type", "text/html; charset=utf-8")
            snap = status.snapshot
            self.finish(render_page(snap, status.plots(snap) if snap is not None else "", status.records()))

    class State(Base):
        def get(self) -> None:
            snap = status.snapshot
            self.set_header("Content-Type", "application/json")
            self.finish(json.dumps(snap.as_json() if snap is not None else None))

    class Plot(Base):
        def get(self) -> None:
            snap = status.snapshot
            if snap is None:
                raise web.HTTPError(404)
            self.set_header("Content-Type", "image/svg+xml")
            self.finish(status.plots(snap, close_up=self.get_query_argument("close_up", "0") == "1"))

    class Listing(Base):
        def get(self) -> None:
            self.set_header("Content-Type", "application/json")
            self.finish(json.dumps(json_ready([{"name": f.name, "size_bytes": f.size_bytes, "mtime_s": f.mtime_s}
                                               for f in status.records()])))

    class Download(Base):
        async def get(self, name: str) -> None:
            if name not in {f.name for f in status.records()}:
                raise web.HTTPError(404)
            try:
                folder = os.open(status.records_dir, os.O_RDONLY | os.O_DIRECTORY)
                try:
                    fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_NONBLOCK", 0), dir_fd=folder)
                finally:
                    os.close(folder)
            except OSError:
                raise web.HTTPError(404) from None
            with os.fdopen(fd, "rb") as handle:
                size = os.fstat(handle.fileno()).st_size
                if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                    raise web.HTTPError(404)
                self.set_header("Content-Type", "application/octet-stream")
                self.set_header("Content-Disposition", f"attachment; filename*=UTF-8''{quote(name, safe='')}")
                self.set_header("Content-Length", size)
                if self.request.method == "HEAD":
                    return
                left = size
                while left > 0:
                    chunk = handle.read(min(CHUNK_BYTES, left))
                    if not chunk:
                        break   # truncated meanwhile: the client sees a short body
                    left -= len(chunk)
                    self.write(chunk)
                    try:
                        await self.flush()
                    except StreamClosedError:
                        return   # the client went away

    return web.Application([(r"/", Page), (r"/state\.json", State), (r"/plot\.svg", Plot),
                            (r"/records/", Listing), (r"/records/(.+)", Download)],
                           default_handler_class=_not_found(Base), log_function=lambda handler: None,
                           compress_response=False)


def _not_found(base):
    class NotFound(base):
        def get(self, *args) -> None:
            raise web.HTTPError(404)

    return NotFound

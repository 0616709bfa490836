"""The viewer's HTTP + WebSocket server (the optional extra ``viewer``: ``pip install -e .[viewer]``).

One port serves the page (``GET /``, ``/viewer.js``, ``/viewer.css``), the latest frame's statistics
(``GET /stats.json``) and one WebSocket at ``/ws``: JSON text messages from the page (``protocol.py``), frames
back as binary messages ``[uint32 LE header length][header JSON][JPEG]`` plus JSON text messages of type
``state`` (shared settings changed) and ``error`` (a message was rejected; the session goes on).

Each client has a one-frame slot: a new frame replaces one not yet sent (dropped, never queued), so a client
that falls behind sees the newest frame next. Rendering and encoding run on the session's render thread, which
hands each frame to the event loop and waits (at most ``SEND_WAIT_S``) until it has been written to every client
that was ready for it before it takes the next gaze: one frame is in flight, and its send does not compete with
the next frame's Python work for the GIL. A client still busy with an earlier frame is not waited for.
"""

from __future__ import annotations

import asyncio
import http
import json
import logging
import threading
import time
from pathlib import Path
from typing import Optional
from urllib.parse import urlsplit

try:
    from websockets.asyncio.server import serve
    from websockets.datastructures import Headers
    from websockets.exceptions import ConnectionClosed
    from websockets.http11 import Response
except ImportError as e:  # pragma: no cover - exercised only without the extra
    raise ImportError("foveawarp view needs the 'viewer' extra: pip install -e .[viewer] "
                      f"(missing: {e.name})") from None

from .protocol import ProtocolError, error_message, parse_message
from .session import ViewerSession

__all__ = ["ViewerServer"]

log = logging.getLogger("foveawarp.viewer")

STATIC_DIR = Path(__file__).resolve().parent / "static"
STATIC_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
    "/viewer.css": ("viewer.css", "text/css; charset=utf-8"),
}
MAX_CLIENTS = 8
MAX_INCOMING_BYTES = 2**16   # a client message above this closes its connection (1009); above 4096 chars: error
SEND_WAIT_S = 0.1            # longest wait of the render thread for a frame's send (then it renders the next)


class _Delivery:
    """The clients that still owe the render thread the send of one frame (event loop thread only, except
    ``event``, which the render thread waits on)."""

    __slots__ = ("pending", "event")

    def __init__(self):
        self.pending = 0
        self.event = threading.Event()

    def settle(self) -> None:
        self.pending -= 1
        if self.pending <= 0:
            self.event.set()


class _Client:
    def __init__(self, ws):
        self.ws = ws
        self.frame = None            # (payload, meta, delivery) not yet sent: replaced, never queued
        self.busy = False            # sending a frame now
        self.state = None            # latest state message not yet sent
        self.errors = []             # render errors to tell this client
        self.wake = asyncio.Event()
        self.send_lock = asyncio.Lock()
        self.sent = 0
        self.dropped = 0


class ViewerServer:
    """Serve ``session`` on ``host``:``port`` (port 0 picks a free one; see ``.port`` after ``start``)."""

    def __init__(self, session: ViewerSession, host: str = "127.0.0.1", port: int = 8765,
                 max_clients: int = MAX_CLIENTS):
        if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise ValueError(f"port must be an integer in [0, 65535], got {port!r}")
        if not isinstance(host, str) or not host:
            raise ValueError(f"host must be a host name or address, got {host!r}")
        self.session = session
        self.host = host
        self.port = port
        self.max_clients = max_clients
        self._clients: set = set()
        self._server = None
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._static = {path: ((STATIC_DIR / name).read_bytes(), ctype) for path, (name, ctype) in STATIC_FILES.items()}
        self._thread: Optional[threading.Thread] = None
        self._stopped: Optional[asyncio.Event] = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    # -- lifecycle --------------------------------------------------------------------------------------
    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopped = asyncio.Event()
        self._server = await serve(self._handler, self.host, self.port, process_request=self._http,
                                   max_size=MAX_INCOMING_BYTES, compression=None, ping_interval=20, ping_timeout=20,
                                   write_limit=2**16)
        socks = self._server.sockets
        if socks:
            self.port = int(socks[0].getsockname()[1])
        self.session.start(self._publish_threadsafe, self._error_threadsafe)

    async def close(self) -> None:
        self.session.stop()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    async def serve_forever(self) -> None:
        await self.start()
        try:
            await self._stopped.wait()
        finally:
            await self.close()

    def start_in_thread(self, timeout: float = 60.0) -> "ViewerServer":
        """Run the server on its own event loop in a daemon thread (tests, benchmarks); returns once it
        listens. Stop it with ``stop()``."""
        ready = threading.Event()
        failure = []

        def main():
            async def run():
                try:
                    await self.start()
                except BaseException as e:  # report to the starting thread
                    failure.append(e)
                    ready.set()
                    return
                ready.set()
                try:
                    await self._stopped.wait()
                finally:
                    await self.close()

            asyncio.run(run())

        self._thread = threading.Thread(target=main, name="foveawarp-viewer", daemon=True)
        self._thread.start()
        if not ready.wait(timeout):
            raise RuntimeError(f"viewer server did not start within {timeout} s")
        if failure:
            raise failure[0]
        return self

    def stop(self, timeout: float = 30.0) -> None:
        """Stop a server started with ``start_in_thread`` (or ``serve_forever`` from another thread)."""
        if self._loop is not None and self._stopped is not None:
            try:
                self._loop.call_soon_threadsafe(self._stopped.set)
            except RuntimeError:  # loop already closed
                pass
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    # -- HTTP -----------------------------------------------------------------------------------------------
    def _http(self, connection, request):
        path = urlsplit(request.path).path
        if path == "/ws":
            origin = request.headers.get("Origin")
            host = request.headers.get("Host")
            if origin is not None and urlsplit(origin).netloc != host:
                # a page from another site must not steer (or watch) this viewer
                return _response(403, b"cross-origin WebSocket refused\n", "text/plain; charset=utf-8")
            if len(self._clients) >= self.max_clients:
                return _response(503, b"too many viewer clients\n", "text/plain; charset=utf-8")
            return None
        if path in self._static:
            body, ctype = self._static[path]
            return _response(200, body, ctype)
        if path == "/stats.json":
            body = json.dumps(self.session.stats_snapshot()).encode()
            return _response(200, body, "application/json")
        if path == "/favicon.ico":
            return _response(204, b"", "text/plain")
        return _response(404, b"not found\n", "text/plain; charset=utf-8")

    # -- WebSocket ---------------------------------------------------------------------------------------
    async def _handler(self, ws) -> None:
        client = _Client(ws)
        self._clients.add(client)
        self.session.set_clients(len(self._clients))
        sender = asyncio.create_task(self._sender(client))
        try:
            await self._send(client, json.dumps(self.session.state_message()))
            async for raw in ws:
                t = time.perf_counter()
                try:
                    msg = parse_message(raw, self.session.limits)
                    changed = self.session.apply(msg, t_arrival=t)
                except ProtocolError as e:
                    await self._send(client, error_message(e))
                    continue
                if changed:
                    state = json.dumps(self.session.state_message())
                    for c in list(self._clients):
                        c.state = state
                        c.wake.set()
        except ConnectionClosed:
            pass
        finally:
            self._clients.discard(client)
            self.session.set_clients(len(self._clients))
            if client.frame is not None:     # never sent: the render thread does not wait for it
                _settle(client.frame[2])
                client.frame = None
            sender.cancel()
            try:
                await sender
            except (asyncio.CancelledError, ConnectionClosed):
                pass

    async def _send(self, client: _Client, data) -> None:
        async with client.send_lock:
            await client.ws.send(data)

    async def _sender(self, client: _Client) -> None:
        """Send this client's pending state, errors and newest frame; one frame in flight at most."""
        try:
            while True:
                await client.wake.wait()
                client.wake.clear()
                if client.state is not None:
                    state, client.state = client.state, None
                    await self._send(client, state)
                while client.errors:
                    await self._send(client, error_message(client.errors.pop(0)))
                if client.frame is not None:
                    (payload, meta, delivery), client.frame = client.frame, None
                    client.busy = True
                    try:
                        await self._send(client, payload)
                        client.sent += 1
                        self.session.frame_left(meta, time.perf_counter())
                    finally:
                        client.busy = False
                        _settle(delivery)
        except ConnectionClosed:
            return

    # -- from the render thread --------------------------------------------------------------------------
    def _publish_threadsafe(self, payload: bytes, meta: dict) -> None:
        """Hand a frame to the event loop and wait (at most ``SEND_WAIT_S``) until it has left for every client
        that was ready for it."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            delivery = _Delivery()
            try:
                loop.call_soon_threadsafe(self._on_frame, payload, meta, delivery)
            except RuntimeError:  # loop closing
                return
            delivery.event.wait(SEND_WAIT_S)

    def _on_frame(self, payload: bytes, meta: dict, delivery: Optional[_Delivery] = None) -> None:
        for c in list(self._clients):
            if c.frame is not None:      # the previous frame never went out: dropped
                c.dropped += 1
                _settle(c.frame[2])
            owes = delivery is not None and not c.busy   # a client busy sending is not waited for
            c.frame = (payload, meta, delivery if owes else None)
            if owes:
                delivery.pending += 1
            c.wake.set()
        if delivery is not None and delivery.pending <= 0:
            delivery.event.set()

    def _error_threadsafe(self, text: str) -> None:
        log.warning("%s", text)
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._on_error, text)
            except RuntimeError:
                pass

    def _on_error(self, text: str) -> None:
        state = json.dumps(self.session.state_message())  # e.g. the scene went back to one that loads
        for c in list(self._clients):
            if len(c.errors) < 16:
                c.errors.append(text)
            c.state = state
            c.wake.set()


def _settle(delivery: Optional[_Delivery]) -> None:
    if delivery is not None:
        delivery.settle()


def _response(status: int, body: bytes, ctype: str) -> Response:
    st = http.HTTPStatus(status)
    headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))), ("Cache-Control", "no-store"),
                       ("X-Content-Type-Options", "nosniff"), ("Connection", "close")])
    return Response(st.value, st.phrase, headers, body)


"""The live view's web server (aiohttp): one page, its static assets, and a WebSocket of snapshots.

Read-only by construction: it holds a :class:`~tools.view.source.Feed` (snapshots of what the
listener decoded) and nothing that reaches the bus. Every ``1 / rate_hz`` s one snapshot is
taken and serialised once; each browser has a bounded queue of them. A browser that does not keep
up loses its oldest queued snapshots (counted) and gets a full one (the whole history) instead,
so its plots stay whole; neither the snapshot task nor the bus reader ever waits for a browser.

Bound to 127.0.0.1 by default. Any other address needs a token, checked on every WebSocket
connect (``/ws?token=...``); a wrong or missing one is refused with 403 and counted. What a
browser sends is ignored unless it is one of the few known requests (``{"type": "resync"}`` for
the full history, ``{"type": "ping"}``); anything else is counted as malformed.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import threading
from dataclasses import dataclass
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from config.errors import AiderError
from tools.view.source import Feed

STATIC = resources.files("tools.view") / "static"
LOOPBACK = "127.0.0.1"


def check_bind(host: str, token: str | None) -> None:
    """A view reachable from other machines needs a token: refuse it otherwise (one line)."""
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if not loopback and not token:
        raise AiderError(f"--host {host} makes the view reachable from other machines: give --token SECRET "
                         "(the page is then opened as http://HOST:PORT/?token=SECRET)")


@dataclass(eq=False)  # each browser its own (hashed by identity)
class Client:
    queue: asyncio.Queue[str]
    dropped: int = 0


@dataclass
class ServerStats:
    clients: int = 0
    connects: int = 0
    refused: int = 0  # WebSocket connects without the right token
    malformed: int = 0  # client messages that are not a known request
    dropped: int = 0  # snapshots a slow browser never got (replaced by a full one)
    snapshots: int = 0  # broadcast rounds
    resyncs: int = 0
    sent_bytes: int = 0

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class ViewServer:
    def __init__(self, feed: Feed, *, host: str = LOOPBACK, port: int = 8050, token: str | None = None,
                 rate_hz: float = 25.0, queue_len: int = 4, title: str = "") -> None:
        check_bind(host, token)
        if not 1.0 <= rate_hz <= 100.0:
            raise AiderError(f"--rate {rate_hz}: the page updates between 1 and 100 times a second")
        self.feed, self.host, self.port, self.token = feed, host, port, token
        self.period_s, self.queue_len, self.title = 1.0 / rate_hz, queue_len, title
        self.stats = ServerStats()
        self.clients: set[Client] = set()
        self._runner: web.AppRunner | None = None
        self._task: asyncio.Task | None = None
        self.url = ""

    # -- the app ---------------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/status.json", self._status)
        app.router.add_get("/favicon.ico", self._no_icon)
        app.router.add_static("/static/", STATIC, show_index=False)
        return app

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def _no_icon(self, request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def _status(self, request: web.Request) -> web.Response:
        if not self._authorised(request):
            self.stats.refused += 1
            raise web.HTTPForbidden(text="a token is needed\n")
        return web.json_response({"server": self.stats.as_dict(), "title": self.title})

    def _authorised(self, request: web.Request) -> bool:
        if not self.token:
            return True
        return hmac.compare_digest(request.query.get("token", ""), self.token)

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            self.stats.refused += 1
            raise web.HTTPForbidden(text="a token is needed\n")
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096)
        await ws.prepare(request)
        client = Client(asyncio.Queue(self.queue_len))
        client.queue.put_nowait(self._full())
        self.clients.add(client)
        self.stats.clients, self.stats.connects = len(self.clients), self.stats.connects + 1
        sender = asyncio.create_task(self._send(ws, client))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT or not self._request(msg.data, client):
                    self.stats.malformed += 1
        finally:
            self.clients.discard(client)
            self.stats.clients = len(self.clients)
            sender.cancel()
        return ws

    def _request(self, text: str, client: Client) -> bool:
        try:
            req = json.loads(text)
        except ValueError:
            return False
        kind = req.get("type") if isinstance(req, dict) else None
        if kind == "resync":
            self._replace_queued(client, self._full())
            self.stats.resyncs += 1
        return kind in ("resync", "ping")

    async def _send(self, ws: web.WebSocketResponse, client: Client) -> None:
        try:
            while True:
                text = await client.queue.get()
                await ws.send_str(text)
                self.stats.sent_bytes += len(text)
        except (ConnectionError, RuntimeError):  # the browser went away mid-send
            pass

    # -- the snapshots ---------------------------------------------------------------------------

    def _full(self) -> str:
        return json.dumps({"kind": "full", "title": self.title, **self.feed.snapshot(-1)}, allow_nan=False)

    def _replace_queued(self, client: Client, text: str) -> None:
        while not client.queue.empty():
            client.queue.get_nowait()
            client.dropped += 1
            self.stats.dropped += 1
        client.queue.put_nowait(text)

    async def _broadcast(self) -> None:
        since = self.feed.newest_sample()
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            next_at += self.period_s
            await asyncio.sleep(max(0.0, next_at - loop.time()))
            if next_at < loop.time() - 1.0:  # far behind (a stopped process): start the schedule anew
                next_at = loop.time()
            if not self.clients:  # a browser that connects gets the full history, then what is newer
                since = self.feed.newest_sample()
                continue
            snap = self.feed.snapshot(since)
            samples = snap["series"]["samples"]
            if samples:
                since = samples[-1][0]
            text = json.dumps({"kind": "delta", "title": self.title, **snap}, allow_nan=False)
            full = None
            for client in list(self.clients):
                if client.queue.full():
                    full = full or self._full()
                    self._replace_queued(client, full)
                else:
                    client.queue.put_nowait(text)
            self.stats.snapshots += 1

    # -- running ---------------------------------------------------------------------------------

    async def start(self) -> str:
        """Bind and serve; the page's address (the port chosen when ``port`` is 0)."""
        self._runner = web.AppRunner(self.app(), access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=True)
        try:
            await site.start()
        except OSError as exc:
            await self._runner.cleanup()
            raise AiderError(f"cannot serve the view on {self.host}:{self.port}: {exc.strerror or exc}") from None
        port = self._runner.addresses[0][1]
        self._task = asyncio.create_task(self._broadcast())
        host = f"[{self.host}]" if ":" in self.host else self.host
        self.url = f"http://{host}:{port}/" + (f"?token={self.token}" if self.token else "")
        return self.url

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
        if self._runner is not None:
            await self._runner.cleanup()


class ServerThread(threading.Thread):
    """A :class:`ViewServer` on its own event loop in a daemon thread (beside a walk in this process)."""

    def __init__(self, server: ViewServer) -> None:
        super().__init__(name="aider-view-server", daemon=True)
        self.server = server
        self.loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self.server.start())
        except BaseException as exc:  # handed to the starting thread
            self.error = exc
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()
        self.loop.run_until_complete(self.server.stop())
        self.loop.close()

    def start_serving(self) -> str:
        self.start()
        self._ready.wait()
        if self.error is not None:
            raise self.error
        return self.server.url

    def close(self) -> None:
        if self.loop.is_running():
            self.loop.call_soon_threadsafe(self.loop.stop)
        self.join(timeout=5.0)

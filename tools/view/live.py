"""The live view beside a walk in this process (``aider-exo walk --view``, ``aider-exo bench view``):
a passive listener on the walk's bus and the web server, each in a background thread."""

from __future__ import annotations

from typing import Any

from protocol.clock import MonotonicClock


class LiveView:
    """The view of ``cfg``'s walk on the bus ``bus_cfg``: opened before the walk (it sees the
    boot-ups), its reader and server threads started by :meth:`start`, both stopped by :meth:`close`."""

    def __init__(self, cfg: Any, bus_cfg: Any, *, port: int = 8050, rate_hz: float = 25.0) -> None:
        from protocol.bus import open_bus
        from tools.view import make_feed
        from tools.view.server import ServerThread, ViewServer
        from tools.view.source import BusReader, ListenOnly

        self.feed = make_feed(cfg)
        self.bus = ListenOnly(open_bus(bus_cfg))
        self.reader = BusReader(self.bus, self.feed, poll_s=0.05)
        self.server = ServerThread(ViewServer(self.feed, port=port, rate_hz=rate_hz,
                                              title=f"walk on {bus_cfg.interface}:{bus_cfg.channel}"))
        self.clock = MonotonicClock()

    def start(self) -> str:
        """Start listening and serving; the page's address."""
        self.reader.start()
        try:
            return self.server.start_serving()
        except BaseException:
            self.reader.stop()
            self.bus.shutdown()
            raise

    def close(self, linger_s: float = 0.0) -> dict[str, Any]:
        """Stop (after serving ``linger_s`` more seconds); what the view saw and served."""
        if linger_s > 0:
            self.clock.sleep_until(self.clock.now_ns() + int(linger_s * 1e9))
        self.reader.stop()
        self.reader.join(timeout=self.reader.DRAIN_S + 2.0)
        self.server.close()
        self.bus.shutdown()
        return {"url": self.server.server.url, "frames": self.feed.model.frames, "server": self.server.server.stats.as_dict(),
                "sends_refused": self.bus.sends_refused, "reader_error": self.reader.error}

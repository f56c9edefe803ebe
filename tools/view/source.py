"""Where the view's frames come from: a bus it only listens to, or a recorded trace at a pace.

One reader thread per view puts every frame into a :class:`Feed` (the :class:`ViewModel` behind a
lock); the web server only takes snapshots, so a slow browser can never hold up the reader.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from typing import Any

import can

import protocol.bus as protocol_bus
from config.errors import AiderError
from protocol.clock import MonotonicClock, epoch_s
from tools.view.model import ViewModel


class Feed:
    """The model behind one lock, and when (wall clock) the newest frame came."""

    def __init__(self, model: ViewModel) -> None:
        self.model = model
        self.lock = threading.Lock()
        self.last_rx_wall: float | None = None  # wall time (epoch s) of the newest frame
        self.source_ended = False  # a trace that has been read to its end

    def put(self, msg: Any) -> None:
        with self.lock:
            self.model.feed(msg)
            self.last_rx_wall = epoch_s()

    def newest_sample(self) -> int:
        """The number of the newest per-tick sample (-1: none yet)."""
        with self.lock:
            return self.model.sample_count - 1

    def snapshot(self, since: int = -1) -> dict[str, Any]:
        with self.lock:
            snap = self.model.snapshot(since)
            last = self.last_rx_wall
        now = epoch_s()
        snap["last_rx_wall"] = last
        snap["stale_s"] = None if last is None else round(now - last, 3)
        snap["source_ended"] = self.source_ended
        snap["server_wall"] = now
        return snap


class ListenOnly(protocol_bus.ListenOnly):
    """The view's only bus handle: it can only read, so no code path of the view transmits."""

    REFUSAL = "the live view is a passive listener: it never sends a frame"


class BusReader(threading.Thread):
    """Reads ``bus`` until :meth:`stop`, every frame into ``feed``; at the stop, the frames already
    queued too (those sent before it, for at most ``DRAIN_S``), so that a walk's view ends complete."""

    DRAIN_S = 10.0

    def __init__(self, bus: ListenOnly, feed: Feed, *, poll_s: float = 0.1) -> None:
        super().__init__(name="aider-view-bus", daemon=True)
        self.bus, self.feed, self.poll_s = bus, feed, poll_s
        self._stop_event = threading.Event()
        self._stopped_at = float("inf")
        self.error: str | None = None

    def run(self) -> None:
        recv, put = self.bus.recv, self.feed.put
        try:
            while not self._stop_event.is_set():
                msg = recv(self.poll_s)
                if msg is not None:
                    put(msg)
            clock = MonotonicClock()
            end_ns = clock.now_ns() + int(self.DRAIN_S * 1e9)
            while clock.now_ns() < end_ns and (msg := recv(0.0)) is not None and msg.timestamp <= self._stopped_at:
                put(msg)
        except (can.CanError, OSError, ValueError) as exc:  # the bus went away (shut down, interface gone)
            if not self._stop_event.is_set():
                self.error = f"the bus reader stopped: {exc}"

    def stop(self) -> None:
        self._stopped_at = epoch_s()  # bus timestamps are wall-clock times
        self._stop_event.set()


class TraceReader(threading.Thread):
    """Plays ``frames`` into ``feed`` at ``speed`` times the recorded pace (0: as fast as read)."""

    def __init__(self, frames: Iterable[Any], feed: Feed, *, speed: float = 1.0) -> None:
        super().__init__(name="aider-view-trace", daemon=True)
        self.frames, self.feed, self.speed = frames, feed, speed
        self._stop_event = threading.Event()
        self.error: str | None = None
        self.played = 0

    def run(self) -> None:
        clock = MonotonicClock()
        start_ns = first_ts = None
        wait = self._stop_event.wait
        try:
            for frame in self.frames:
                if self._stop_event.is_set():
                    return
                if self.speed > 0:
                    if first_ts is None:
                        start_ns, first_ts = clock.now_ns(), frame.timestamp
                    ahead = (frame.timestamp - first_ts) / self.speed - (clock.now_ns() - start_ns) / 1e9
                    if ahead > 0.002 and wait(ahead):  # sleep in batches of frames; stop wakes it
                        return
                self.feed.put(frame)
                self.played += 1
        except AiderError as exc:  # an unreadable trace: said on the page and by the command
            self.error = str(exc)
        finally:
            self.feed.source_ended = True

    def stop(self) -> None:
        self._stop_event.set()

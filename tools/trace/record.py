"""Recording a bus into any python-can log format, with rotation and a metadata sidecar.

The writer is python-can's for the suffix (``.log`` candump, ``.asc``, ``.blf``, ``.trc``,
``.csv``, ``.mf4`` where asammdf is installed). Each file is written as ``NAME.partial.EXT`` and
renamed to ``NAME.EXT`` once closed, so a recording that was killed is never mistaken for a
complete one. Rotation starts a new part (``NAME_000.EXT``, ``NAME_001.EXT``, ...) when a part
reaches a size or covers a span of trace time; the sidecar ``NAME.EXT.meta.json`` lists them.

Two sources: a live bus (:func:`record_bus`; SocketCAN, with its kernel timestamps), and the
whole lock-step pipeline in this process (:func:`record_walk`: controller, node boards and the
simulation on a virtual bus), whose frames are put on the simulated time base: the first frame at
0, tick ``k``'s SYNC ``k`` x 20 ms after the first SYNC, every other frame at its real delay after
the SYNC of its tick.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from protocol.bus import virtual_bus
from protocol.clock import TICK_MS, TICK_S, Clock
from protocol.codec import Codec, Decoded
from tools.trace import TraceError
from tools.trace.files import SIDECAR_SCHEMA, partial_path, sidecar_path, write_json

WRITE_SUFFIXES = (".log", ".asc", ".blf", ".trc", ".csv", ".mf4")


def check_writable(path: Path, *, overwrite: bool) -> None:
    suffix = path.suffix.lower()
    if suffix not in WRITE_SUFFIXES:
        raise TraceError(f"{path}: cannot record to {suffix or '(no suffix)'!r}; formats: {', '.join(WRITE_SUFFIXES)}")
    if suffix == ".mf4" and importlib.util.find_spec("asammdf") is None:
        raise TraceError(f"{path}: recording .mf4 needs asammdf (pip install asammdf)")
    if not path.parent.is_dir():
        raise TraceError(f"{path.parent}: no such folder")
    if path.exists() and not overwrite:
        raise TraceError(f"{path} exists (--overwrite replaces it)")


@dataclass
class TraceWriter:
    """Frames (python-can messages) into ``path`` by its suffix, rotated on size or trace time."""

    path: Path
    rotate_bytes: int | None = None
    rotate_s: float | None = None
    frames: int = 0
    first_timestamp: float | None = None
    last_timestamp: float | None = None
    parts: list[Path] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        self._writer: Any = None
        self._part_start: float | None = None

    @property
    def rotating(self) -> bool:
        return self.rotate_bytes is not None or self.rotate_s is not None

    def _final(self, index: int) -> Path:
        return self.path.with_name(f"{self.path.stem}_{index:03d}{self.path.suffix}") if self.rotating else self.path

    def _open(self, timestamp: float) -> None:
        target = partial_path(self._final(len(self.parts)))
        try:
            self._writer = can.Logger(str(target))
        except (OSError, ValueError, ImportError) as exc:
            raise TraceError(f"{target}: cannot write ({exc})") from None
        self._part_start = timestamp

    def _close_part(self) -> None:
        if self._writer is None:
            return
        final = self._final(len(self.parts))
        self._writer.stop()
        self._writer = None
        os.replace(partial_path(final), final)
        self.parts.append(final)

    def write(self, msg: can.Message) -> None:
        if self._writer is not None and self.rotating:
            too_big = self.rotate_bytes is not None and self._writer.file_size() >= self.rotate_bytes
            too_long = self.rotate_s is not None and msg.timestamp - self._part_start >= self.rotate_s
            if too_big or too_long:
                self._close_part()
        if self._writer is None:
            self._open(msg.timestamp)
        self._writer.on_message_received(msg)
        self.frames += 1
        if self.first_timestamp is None:
            self.first_timestamp = msg.timestamp
        self.last_timestamp = msg.timestamp

    def close(self, metadata: dict[str, Any]) -> dict[str, Any]:
        """Close the last part and write the sidecar (none without a frame); returns its content."""
        self._close_part()
        meta = {"schema": SIDECAR_SCHEMA, **metadata, "frames": self.frames, "first_timestamp": self.first_timestamp,
                "last_timestamp": self.last_timestamp, "parts": [p.name for p in self.parts]}
        if self.parts:
            write_json(sidecar_path(self.path), meta)
        return meta

    def abort(self) -> None:
        """Stop after an error: the open part keeps its ``.partial`` name."""
        if self._writer is not None:
            try:
                self._writer.stop()
            finally:
                self._writer = None


def record_bus(
    bus: can.BusABC, writer: TraceWriter, clock: Clock, *, count: int | None = None, duration_s: float | None = None,
    idle_timeout_s: float | None = None, stop: Callable[[], bool] = lambda: False, poll_s: float = 0.1,
) -> str:
    """Write every frame ``bus`` receives until a limit or ``stop()``; returns why it ended."""
    start = last_frame = clock.now_ns()
    while True:
        if stop():
            return "stopped"
        now = clock.now_ns()
        if duration_s is not None and now - start >= duration_s * 1e9:
            return "duration"
        if idle_timeout_s is not None and now - last_frame >= idle_timeout_s * 1e9:
            return "idle"
        try:
            msg = bus.recv(timeout=poll_s)
        except can.CanError as exc:  # the interface went down: what was recorded is kept
            return f"bus error: {exc}"
        if msg is None:
            continue
        writer.write(msg)
        last_frame = clock.now_ns()
        if count is not None and writer.frames >= count:
            return "count"


class LockstepRestamper:
    """Puts the frames of a lock-step run on the simulated time base (see the module doc)."""

    def __init__(self, codec: Codec, channel: str) -> None:
        self.codec = codec
        self.channel = channel
        self.start_s = 0.0  # of the first SYNC
        self.sync_id = codec.spec("SYNC").frame_id
        self._tick = 0
        self._sync_wall: float | None = None
        self._last = float("-inf")
        self._held: list[can.Message] = []

    def __call__(self, batch: list[can.Message]) -> list[can.Message]:
        """The frames of ``batch`` (in bus order) restamped; those before the first SYNC are held
        until it comes, then keep their delay before it."""
        if self._sync_wall is None:
            self._held += batch
            first_sync = next((m for m in self._held if m.arbitration_id == self.sync_id), None)
            if first_sync is None:
                return []
            self._sync_wall = first_sync.timestamp
            self.start_s = first_sync.timestamp - self._held[0].timestamp
            batch, self._held = self._held, []
        limit = TICK_S * 0.975  # a frame stays inside its tick, before the next SYNC
        for msg in batch:
            if msg.arbitration_id == self.sync_id:
                decoded = self.codec.decode(msg.arbitration_id, msg.data)
                self._tick = decoded.values.tick if type(decoded) is Decoded else self._tick + 1
                self._sync_wall = msg.timestamp
            delay = min(msg.timestamp - self._sync_wall, limit)
            stamped = self.start_s + self._tick * TICK_MS / 1000.0 + delay
            msg.timestamp = self._last = max(stamped, self._last)
            msg.channel = self.channel
        return batch


def record_walk(cfg: Any, writer: TraceWriter, *, cycles: int, seed: int, mode: str,
                max_time_s: float | None) -> dict[str, Any]:
    """Run the lock-step pipeline in this process (:func:`tools.pipeline.walk`) and record every
    frame on its bus into ``writer``, on the simulated time base, under the channel name of
    ``cfg.bus``."""
    from tools.pipeline import walk

    channel = f"aider-trace-record-{os.getpid()}-{id(writer)}"
    restamp = LockstepRestamper(Codec(), cfg.bus.channel)

    with virtual_bus(channel) as tap:
        def drain(*_: Any) -> None:
            batch = []
            while (msg := tap.recv(timeout=0.0)) is not None:
                batch.append(msg)
            for msg in restamp(batch):
                writer.write(msg)

        outcome = walk(cfg, cycles=cycles, seed=seed, mode=mode, max_time_s=max_time_s, on_tick=drain, channel=channel)
        drain()
    return {
        "kind": "walk",
        "cycles_asked": cycles,
        "mode": mode,
        "ticks": outcome.ticks,
        "final_state": outcome.final_state,
        "cycles_completed": outcome.cycles_completed,
        "fell": outcome.fell,
        # the operator's start, as tools.pipeline.walk gives it: before the first tick
        "operator": {"request_walk_tick": 0},
    }

"""Per-tick telemetry: one record per tick with a fixed schema, written as JSON lines by a thread
that never blocks the tick (docs/FAULTS.md F30).

The tick hands its record to :meth:`TelemetryLog.put`, which only appends to a bounded queue; a
writer thread drains it to the file. When the writer falls behind (slow disk, full disk) the
oldest records are dropped and counted, and a write error stops writing (counted and reported at
``close``) instead of stopping the loop. The first line of the file is the schema: field names,
units and the schema version, so a log can be read without this code.

A log is never truncated: an existing non-empty file at the path (the log of a run that crashed
and was restarted with the same ``--log``) is first moved aside to a dated name beside it,
``NAME.<UTC of its last modification>.jsonl`` (``NAME.20261207T054200Z.jsonl``, ``-1``, ``-2``...
when taken; never over another file), and the new run writes a fresh file at the path
(:attr:`TelemetryLog.previous` says where the old one went).
"""

from __future__ import annotations

import collections
import datetime
import json
import math
import os
import threading
from pathlib import Path
from typing import Any

from config.errors import AiderError

SCHEMA_VERSION = 2

#: field -> (unit, meaning); every record has exactly these fields
FIELDS: dict[str, tuple[str, str]] = {
    "tick": ("", "controller tick number (SYNC)"),
    "state": ("", "gait FSM state"),
    "q_rad": ("rad", "measured joint angles: left hip, left knee, right hip, right knee"),
    "setpoint_rad": ("rad", "commanded positions (null for hold)"),
    "mode": ("", "commanded modes"),
    "stick_force_n": ("N", "left, right stick force"),
    "plantar_n": ("N", "left, right heel + toe force"),
    "trunk_rpy_rad": ("rad", "trunk roll, pitch, yaw"),
    "com_m": ("m", "estimated CoM in the heading frame"),
    "x_ratio": ("", "estimated X_CoM / X_SP (null: undefined)"),
    "gait": ("", "part of the gait while walking: shift, lean or swing (null otherwise)"),
    "step": ("", "index of the current swing's step (null outside swings)"),
    "step_length_m": ("m", "step length of the current swing (null outside swings)"),
    "step_cost_n": ("N", "cost of the step that landed this tick: its mean stick force (paper eq. 10), else null"),
    "theta": ("", "(alpha, Xhat_CoM) of the current swing's compensation (null: fixed step or outside swings)"),
    "work_us": ("us", "controller work of the tick"),
    "lateness_us": ("us", "wake-up lateness of the tick (real time)"),
    "events": ("", "state changes and faults of the tick"),
}


class TelemetryError(AiderError):
    """A telemetry log that cannot be created (one line, naming the file)."""


def move_aside(path: Path) -> Path | None:
    """Move an existing non-empty file at ``path`` to ``NAME.<UTC mtime>.jsonl`` beside it (with
    ``-N`` when that name is taken; never over another file); the new name, or None when there was
    nothing to keep. An :class:`OSError` when it cannot be moved."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    if not path.is_file() or st.st_size == 0:
        return None
    stamp = datetime.datetime.fromtimestamp(st.st_mtime, datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    suffix = path.suffix or ".jsonl"
    for n in range(10_000):
        target = path.with_name(f"{path.stem}.{stamp}{'' if n == 0 else f'-{n}'}{suffix}")
        try:
            os.link(path, target)  # fails when the name is taken: never overwrites
        except FileExistsError:
            continue
        except OSError:  # no hard links on this file system: a checked rename
            if target.exists():
                continue
            os.rename(path, target)
            return target
        os.unlink(path)
        return target
    raise FileExistsError(f"{path}: every dated name for the previous log is taken")


def _clean(value: Any) -> Any:
    """JSON-safe: numpy to lists, non-finite floats to null."""
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


class TelemetryLog:
    def __init__(self, path: str | Path, *, capacity: int = 4096) -> None:
        self.path = Path(path)
        self._queue: collections.deque[dict[str, Any]] = collections.deque()
        self._capacity = capacity
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closing = False
        self.written = 0
        self.dropped = 0
        self.error: str | None = None
        self.previous: Path | None = None  # where an existing log at the path was moved (never truncated)
        schema = {"schema": "aider-exo controller telemetry", "version": SCHEMA_VERSION,
                  "fields": {k: {"unit": u, "meaning": m} for k, (u, m) in FIELDS.items()}}
        try:
            self.previous = move_aside(self.path)
            # "x": a new file (an existing one was moved aside); "w" only over an empty file or a device
            self._file = self.path.open("w" if self.path.exists() else "x", encoding="utf-8")
            self._file.write(json.dumps(schema) + "\n")
        except OSError as exc:  # a bad --log path is the user's error, not a traceback
            raise TelemetryError(f"{self.path}: cannot write the telemetry log ({exc.strerror or exc})") from None
        self._thread = threading.Thread(target=self._run, name="telemetry", daemon=True)
        self._thread.start()

    def put(self, record: dict[str, Any]) -> None:
        """Queue one tick's record (never blocks; the oldest is dropped when the queue is full)."""
        if set(record) != set(FIELDS):
            raise ValueError(f"telemetry record fields differ from the schema: {sorted(set(record) ^ set(FIELDS))}")
        with self._lock:
            if len(self._queue) >= self._capacity:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(record)
        self._wake.set()

    def _run(self) -> None:
        while True:
            self._wake.wait(0.5)
            self._wake.clear()
            while True:
                with self._lock:
                    if not self._queue:
                        break
                    batch = list(self._queue)
                    self._queue.clear()
                if self.error is None:
                    try:
                        self._file.write("".join(json.dumps({k: _clean(r[k]) for k in FIELDS}) + "\n" for r in batch))
                        self._file.flush()
                        self.written += len(batch)
                    except (OSError, ValueError) as exc:
                        self.error = f"telemetry write failed: {exc}"
                if self.error is not None:
                    self.dropped += len(batch)
            if self._closing:
                return

    def close(self) -> dict[str, Any]:
        """Write what is queued, close the file, and report what happened."""
        self._closing = True
        self._wake.set()
        self._thread.join(timeout=30)
        try:
            self._file.close()
        except OSError as exc:
            self.error = self.error or f"telemetry close failed: {exc}"
        return {"path": str(self.path), "written": self.written, "dropped": self.dropped, "error": self.error,
                "previous": str(self.previous) if self.previous is not None else None}


def read_log(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The schema line and the records of a telemetry file."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    return json.loads(lines[0]), [json.loads(line) for line in lines[1:] if line]

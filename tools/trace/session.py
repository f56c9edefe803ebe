"""The session recorder behind ``aider-exo record``: every frame of a channel into rotating files.

Each file is can-utils' log format (``candump -L``: ``(timestamp) channel ID#DATA``, what
``aider-exo trace decode`` and ``canplayer -I`` read), named ``CHANNEL_YYYYMMDDTHHMMSSZ_NNNNNN.log``
(the UTC time it was opened, then a sequence number that goes on from the highest one already in
the folder for that channel). A file is written as ``NAME.log.part`` and renamed to ``NAME.log``
once closed (flushed and fsynced first), so a finished file is always whole; the ``.part`` file is
the one being written, flushed after every batch of frames. No name is ever reused: a name whose
file or ``.part`` exists is skipped, and the ``.part`` is created exclusively.

A file is finished when the next frame would take it past ``max_bytes``, or once it is
``max_seconds`` old (also on a quiet bus). With ``keep``, after each finished file only the newest
``keep`` finished files of the channel in the folder remain (by sequence number; earlier runs'
files count). Before each batch of frames, at most once a second, the free space of the folder is
probed (``shutil.disk_usage``, injectable); below ``min_free_bytes`` the current file is finished
and the recording stops (that batch is not written).
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import can

from protocol.clock import Clock, MonotonicClock, epoch_s
from tools.trace import TraceError

#: exit statuses of ``aider-exo record`` (1 is a one-line error before or during recording)
EXIT_STOPPED = 0  # SIGTERM or SIGINT: the current file finished
EXIT_DISK_FLOOR = 3  # free space below --min-free-mb: the current file finished
EXIT_BUS_ERROR = 4  # the interface failed (went down, adapter unplugged): the current file finished

PART = ".part"
CAN_ERR_FLAG = 0x20000000
DISK_CHECK_NS = 1_000_000_000  # the free-space probe runs at most once a second
NAME_RE = re.compile(r"(?P<channel>.+)_(?P<utc>\d{8}T\d{6}Z)_(?P<seq>\d{6,})\.log(?P<part>\.part)?")


def channel_label(channel: str) -> str:
    """``channel`` as one word for file names and log lines (anything but ``A-Za-z0-9._-`` becomes ``-``)."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", str(channel)) or "can"


def candump_line(msg: can.Message, channel: str) -> str:
    """One frame as ``candump -L`` writes it (classic, remote, error and CAN FD frames)."""
    data = bytes(msg.data or b"").hex().upper()
    if msg.is_error_frame:
        return f"({msg.timestamp:.6f}) {channel} {CAN_ERR_FLAG | msg.arbitration_id:08X}#{data}\n"
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    if msg.is_remote_frame:
        return f"({msg.timestamp:.6f}) {channel} {ident}#R{msg.dlc if msg.dlc else ''}\n"
    if msg.is_fd:
        flags = (1 if msg.bitrate_switch else 0) | (2 if msg.error_state_indicator else 0)
        return f"({msg.timestamp:.6f}) {channel} {ident}##{flags:X}{data}\n"
    return f"({msg.timestamp:.6f}) {channel} {ident}#{data}\n"


def disk_free(folder: Path) -> int:
    """Bytes free for an unprivileged user on the file system of ``folder``."""
    return shutil.disk_usage(folder).free


def session_files(folder: Path, channel: str) -> list[tuple[int, Path]]:
    """The finished files of ``channel`` in ``folder`` as (sequence number, path), oldest first."""
    label = channel_label(channel)
    found = []
    for path in folder.iterdir():
        m = NAME_RE.fullmatch(path.name)
        if m and m["channel"] == label and not m["part"]:
            found.append((int(m["seq"]), path))
    return sorted(found)


def check_order(paths: Iterable[str | Path]) -> list[str]:
    """For the recorder's files given to a command that needs them in recording order (``trace
    resim``): a :class:`TraceError` when they are given out of order (by channel and sequence
    number), warnings for sequence numbers missing between them (a file deleted by ``--keep`` or by
    hand: its frames are not in the recording). Files of other names are not checked."""
    named = [(Path(p), NAME_RE.fullmatch(Path(p).name)) for p in paths if str(p) != "-"]
    if len(named) < 2 or not all(m for _, m in named) or len({m["channel"] for _, m in named}) > 1:
        return []
    pairs = list(zip([(p, int(m["seq"])) for p, m in named], [(p, int(m["seq"])) for p, m in named][1:]))
    for (pa, a), (pb, b) in pairs:
        if b <= a:
            raise TraceError(f"{pb.name} comes before {pa.name} in the recording (sequence {b:06d} < {a:06d}): "
                             "give the recorder's files in recording order (their names sort so: can0_*.log)")
    return [f"the recording's file(s) {a + 1:06d}{f' to {b - 1:06d}' if b - a > 2 else ''} not given between "
            f"{pa.name} and {pb.name}: their frames are missing" for (pa, a), (pb, b) in pairs if b - a > 1]


def check_folder(folder: Path) -> None:
    """One line when ``folder`` cannot hold the recording."""
    if not folder.exists():
        raise TraceError(f"{folder}: no such folder (create it, or give --dir an existing one)")
    if not folder.is_dir():
        raise TraceError(f"{folder}: not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise TraceError(f"{folder}: not writable by this user (uid {os.getuid()})")


@dataclass
class SessionRecorder:
    """Frames into rotating, never overwritten, temp-then-renamed candump log files (module doc)."""

    folder: Path
    channel: str
    max_bytes: int | None = None
    max_seconds: float | None = None
    keep: int | None = None
    min_free_bytes: int = 0
    free_bytes: Callable[[Path], int] = disk_free
    clock: Clock = field(default_factory=MonotonicClock)
    wall: Callable[[], float] = epoch_s
    on_finished: Callable[[Path, int, int], None] | None = None  # (file, frames, bytes)
    files: list[Path] = field(default_factory=list)  # finished by this run, in order
    deleted: list[Path] = field(default_factory=list)  # removed by --keep
    frames: int = 0
    bytes: int = 0
    unwritten: int = 0  # frames of the batch refused by the disk floor
    last_free: int | None = None

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        self.label = channel_label(self.channel)
        self._file: BinaryIO | None = None
        self._part: Path | None = None
        self._final: Path | None = None
        self._file_bytes = 0
        self._file_frames = 0
        self._opened_ns = 0
        self._checked_ns: int | None = None
        seqs = [int(m["seq"]) for p in self.folder.iterdir() if (m := NAME_RE.fullmatch(p.name)) and m["channel"] == self.label]
        self._next_seq = max(seqs, default=0) + 1

    @property
    def current(self) -> Path | None:
        """The ``.part`` file being written, if any."""
        return self._part

    # -- the free-space floor -------------------------------------------------------------------

    def space_ok(self, *, force: bool = False) -> bool:
        """Whether the folder has at least ``min_free_bytes`` free; probed at most once a second
        (``force``: now). Between probes the last answer holds."""
        if not self.min_free_bytes:
            return True
        now = self.clock.now_ns()
        if force or self._checked_ns is None or now - self._checked_ns >= DISK_CHECK_NS:
            self._checked_ns = now
            self.last_free = int(self.free_bytes(self.folder))
        return self.last_free >= self.min_free_bytes

    # -- writing --------------------------------------------------------------------------------

    def write(self, batch: Iterable[can.Message]) -> bool:
        """Write a batch of frames; False (nothing written, the current file finished) when the
        free space is below the floor."""
        batch = list(batch)
        if not batch:
            return True
        if not self.space_ok():
            self.unwritten += len(batch)
            self.finish()
            return False
        self.rotate_if_old()
        for msg in batch:
            line = candump_line(msg, self.label).encode("ascii")
            if (self._file is not None and self.max_bytes is not None and self._file_frames
                    and self._file_bytes + len(line) > self.max_bytes):
                self.finish()
            if self._file is None:
                self._open()
            self._file.write(line)  # type: ignore[union-attr]
            self._file_bytes += len(line)
            self._file_frames += 1
            self.frames += 1
            self.bytes += len(line)
        self._file.flush()  # type: ignore[union-attr]  # what is written is in the .part file
        return True

    def rotate_if_old(self) -> None:
        """Finish the current file once it is ``max_seconds`` old (call it on a quiet bus too)."""
        if self._file is not None and self.max_seconds is not None:
            if self.clock.now_ns() - self._opened_ns >= self.max_seconds * 1e9:
                self.finish()

    def _open(self) -> None:
        utc = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(self.wall()))
        while True:
            final = self.folder / f"{self.label}_{utc}_{self._next_seq:06d}.log"
            part = final.with_name(final.name + PART)
            self._next_seq += 1
            if final.exists():
                continue
            try:
                self._file = part.open("xb")  # exclusive: never another writer's file
            except FileExistsError:
                continue
            except OSError as exc:
                raise TraceError(f"{part}: cannot create ({exc.strerror or exc})") from None
            break
        self._part, self._final = part, final
        self._file_bytes = self._file_frames = 0
        self._opened_ns = self.clock.now_ns()

    def finish(self) -> Path | None:
        """Close the current file (flushed, fsynced) and rename it to its final name; returns it."""
        if self._file is None:
            return None
        f, part, final = self._file, self._part, self._final
        assert part is not None and final is not None
        self._file = self._part = self._final = None
        try:
            f.flush()
            os.fsync(f.fileno())
        finally:
            f.close()
        while final.exists():  # never overwrite (only a file put there by hand can be in the way)
            m = NAME_RE.fullmatch(final.name)
            assert m is not None
            final = final.with_name(f"{m['channel']}_{m['utc']}_{self._next_seq:06d}.log")
            self._next_seq += 1
        os.rename(part, final)
        _fsync_folder(self.folder)
        self.files.append(final)
        if self.on_finished is not None:
            self.on_finished(final, self._file_frames, self._file_bytes)
        self._prune()
        return final

    def _prune(self) -> None:
        if self.keep is None:
            return
        finished = session_files(self.folder, self.channel)
        for _, path in finished[:max(0, len(finished) - self.keep)]:
            try:
                path.unlink()
            except FileNotFoundError:
                continue
            self.deleted.append(path)

    def abandon(self) -> None:
        """After a write error: close the current file, which keeps its ``.part`` name."""
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass
            self._file = self._part = self._final = None

    def status(self) -> dict[str, Any]:
        return {
            "files": [p.name for p in self.files],
            "frames": self.frames,
            "bytes": self.bytes,
            "current": self._part.name if self._part is not None else None,
            "deleted": [p.name for p in self.deleted],
            "free_bytes": self.last_free,
        }


def _fsync_folder(folder: Path) -> None:
    """Make a rename durable (the folder's entry); a file system that cannot is left as it is."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def record_session(
    bus: can.BusABC, recorder: SessionRecorder, *, stop: Callable[[], bool], poll_s: float = 0.2,
    batch_max: int = 512, on_idle: Callable[[], None] = lambda: None,
) -> tuple[str, int, str]:
    """Record ``bus`` into ``recorder`` until ``stop()``, the disk floor or a bus error; the current
    file is finished in every case. Returns (reason, exit status, detail). On a stop, the frames
    the interface has already received are written first. ``on_idle`` runs once per loop (the
    status line, the watchdog ping)."""
    drain_until: int | None = None  # once stopping: what the interface holds, for 2 s at most (a flood)
    while True:
        stopping = stop()
        if stopping and drain_until is None:
            drain_until = recorder.clock.now_ns() + 2_000_000_000
        batch: list[can.Message] = []
        error: Exception | None = None
        try:
            msg = bus.recv(timeout=0.0 if stopping else poll_s)
            if msg is not None:
                batch.append(msg)
                while len(batch) < batch_max and (msg := bus.recv(timeout=0.0)) is not None:
                    batch.append(msg)
        except (can.CanError, OSError) as exc:  # the interface went down: what was received is kept
            error = exc
        if batch and not recorder.write(batch):
            return "disk_floor", EXIT_DISK_FLOOR, f"{len(batch)} frame(s) received were not written"
        if error is not None:
            recorder.finish()
            return "bus_error", EXIT_BUS_ERROR, str(error)
        if stopping and (len(batch) < batch_max or recorder.clock.now_ns() >= drain_until):  # drained
            recorder.finish()
            return "signal", EXIT_STOPPED, ""
        recorder.rotate_if_old()
        on_idle()

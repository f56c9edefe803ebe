"""Reading traces of any common format, chosen by the file's suffix, never raising on bad input.

* ``.log``: can-utils' log format (``candump -l`` / ``candump -L``, ``canplayer``'s input), read
  by our own parser: it is several times faster than python-can's, accepts error frames, remote
  frames, CAN FD and ``.``-separated bytes, and counts a garbage line instead of stopping there.
  ``-`` reads the same format from standard input (``candump -L can0 | aider-exo trace decode -``).
* ``.asc`` (Vector), ``.trc`` (PEAK), ``.blf`` (Vector binary), ``.mf4`` (ASAM MDF, needs
  asammdf): python-can's readers, each wrapped so that a line it cannot parse is a counted skip
  and a truncated or corrupt file ends the read with a problem reported, not a traceback. A BLF
  file whose header promises more frames or bytes than it holds is reported as truncated.
* ``.csv``: python-can's CSV layout (``timestamp,arbitration_id,extended,remote,error,dlc,data``
  with base64 data), by our own tolerant parser.

Frames come out as :class:`Frame`, a light record with the attributes of :class:`can.Message`
that :class:`protocol.e2e.Receiver` reads, in file order (several files in the order given).
Every skipped line, problem and backwards timestamp is counted in a :class:`ReadReport`.
"""

from __future__ import annotations

import base64
import binascii
import importlib.util
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TextIO

import can

from tools.trace import TraceError

#: suffixes we read (``-`` is candump's format on standard input)
READ_SUFFIXES = (".log", ".asc", ".blf", ".trc", ".csv", ".mf4")

CAN_EFF_FLAG = 0x80000000
CAN_ERR_FLAG = 0x20000000
EXAMPLES = 5  # skipped lines quoted in a report


class Frame(NamedTuple):
    """One CAN frame of a trace (the :class:`can.Message` attributes the receivers read)."""

    timestamp: float
    arbitration_id: int
    data: bytes
    channel: str | int | None = None
    is_extended_id: bool = False
    is_remote_frame: bool = False
    is_error_frame: bool = False
    is_fd: bool = False
    is_rx: bool = True

    @classmethod
    def from_message(cls, msg: can.Message) -> Frame:
        return cls(float(msg.timestamp), msg.arbitration_id, bytes(msg.data or b""), msg.channel, msg.is_extended_id,
                   msg.is_remote_frame, msg.is_error_frame, msg.is_fd, msg.is_rx)

    def to_message(self) -> can.Message:
        return can.Message(timestamp=self.timestamp, arbitration_id=self.arbitration_id, data=self.data,
                           channel=self.channel, is_extended_id=self.is_extended_id, is_remote_frame=self.is_remote_frame,
                           is_error_frame=self.is_error_frame, is_fd=self.is_fd, is_rx=self.is_rx,
                           dlc=len(self.data), check=False)


@dataclass
class ReadReport:
    """What reading the files of a trace met besides frames."""

    files: list[str] = field(default_factory=list)
    frames: int = 0
    skipped: int = 0  # lines or records that are neither frames nor comments
    examples: list[str] = field(default_factory=list)  # the first few, "file:line: reason"
    problems: list[str] = field(default_factory=list)  # truncated or corrupt files, missing readers
    backwards: int = 0  # frames whose timestamp is earlier than the frame before

    def skip(self, where: str, reason: str) -> None:
        self.skipped += 1
        if len(self.examples) < EXAMPLES:
            self.examples.append(f"{where}: {reason}")

    def as_dict(self) -> dict[str, Any]:
        return {"files": self.files, "frames": self.frames, "skipped_lines": self.skipped,
                "skipped_examples": self.examples, "problems": self.problems, "timestamps_backwards": self.backwards}

    def warnings(self) -> list[str]:
        """One line per kind of trouble met, for the user's screen."""
        out = list(self.problems)
        if self.skipped:
            out.append(f"skipped {self.skipped} line(s) that are not frames, e.g. {self.examples[0]}")
        if self.backwards:
            out.append(f"{self.backwards} timestamp(s) went backwards")
        return out


# -- can-utils log format ------------------------------------------------------------------------


def parse_candump_line(line: str) -> Frame | str | None:
    """One line of can-utils' log format: a :class:`Frame`, ``None`` for a blank or comment line,
    or the reason the line is not a frame."""
    parts = line.split()
    if not parts or parts[0][0] == "#":
        return None
    if len(parts) < 3 or parts[0][0] != "(" or parts[0][-1] != ")":
        return "not a candump log line '(time) interface frame'"
    try:
        timestamp = float(parts[0][1:-1])
    except ValueError:
        return f"bad timestamp {parts[0]!r}"
    is_rx = not (len(parts) > 3 and parts[3] == "T")
    ident, sep, rest = parts[2].partition("#")
    if not sep or len(ident) not in (3, 8):
        return f"bad frame {parts[2]!r}"
    try:
        can_id = int(ident, 16)
    except ValueError:
        return f"bad CAN ID {ident!r}"
    extended = len(ident) == 8
    fd = False
    if rest[:1] == "#":  # CAN FD: ##<flags><data>
        fd, rest = True, rest[2:]
    elif rest[:1] in ("R", "r"):
        dlc_text = rest[1:].split("_")[0]
        if dlc_text and not dlc_text.isdigit():
            return f"bad remote frame {parts[2]!r}"
        return Frame(timestamp, can_id & 0x1FFFFFFF, bytes(int(dlc_text or 0)), parts[1], extended, True, False, False, is_rx)
    if "_" in rest:  # classic frame with its len8_dlc: data_<dlc>
        rest = rest.split("_")[0]
    try:
        data = bytes.fromhex(rest.replace(".", "")) if rest else b""
    except ValueError:
        return f"bad data {rest!r}"
    if len(data) > (64 if fd else 8):
        return f"{len(data)} data bytes"
    if extended and can_id & CAN_ERR_FLAG:
        return Frame(timestamp, can_id & 0x1FFFFFFF, data, parts[1], True, False, True, False, is_rx)
    return Frame(timestamp, can_id & 0x1FFFFFFF, data, parts[1], extended, False, False, fd, is_rx)


def _candump_frames(lines: Iterable[str], name: str, report: ReadReport) -> Iterator[Frame]:
    # The common line "(1.000000) can0 181#0102030405060708" is parsed inline (the decode hot path);
    # every other shape goes through parse_candump_line.
    fromhex = bytes.fromhex
    new = tuple.__new__  # a Frame without its Python-level __new__
    for number, line in enumerate(lines, 1):
        parts = line.split()
        if len(parts) == 3 or (len(parts) == 4 and parts[3] == "R"):
            ident, sep, rest = parts[2].partition("#")
            if (sep and len(ident) == 3 and len(rest) <= 16 and rest[:1] not in ("#", "R", "r")
                    and "_" not in rest and "." not in rest):
                stamp = parts[0]
                if stamp[:1] == "(" and stamp[-1:] == ")":
                    try:
                        yield new(Frame, (float(stamp[1:-1]), int(ident, 16), fromhex(rest), parts[1],
                                          False, False, False, False, True))
                        continue
                    except ValueError:
                        pass  # reported below, with its reason
        result = parse_candump_line(line)
        if type(result) is Frame:
            yield result
        elif result is not None:
            report.skip(f"{name}:{number}", result)


# -- python-can's readers, made tolerant ---------------------------------------------------------


class _ASCReader(can.ASCReader):
    """python-can's ASC reader; a frame line it cannot parse is counted, not raised."""

    def __init__(self, file: Any, report: ReadReport, name: str) -> None:
        super().__init__(file)
        self._report, self._name = report, name

    def _process_classic_can_frame(self, line: str, msg_kwargs: dict[str, Any]) -> can.Message | None:
        try:
            return super()._process_classic_can_frame(line, msg_kwargs)
        except (ValueError, IndexError, KeyError, TypeError) as exc:
            self._report.skip(self._name, f"bad ASC frame {line.strip()[:40]!r} ({exc})")
            return None

    def _process_fd_can_frame(self, line: str, msg_kwargs: dict[str, Any]) -> can.Message | None:
        try:
            return super()._process_fd_can_frame(line, msg_kwargs)
        except (ValueError, IndexError, KeyError, TypeError) as exc:
            self._report.skip(self._name, f"bad ASC FD frame {line.strip()[:40]!r} ({exc})")
            return None


class _TRCReader(can.TRCReader):
    """python-can's TRC reader; a line it cannot parse is counted, not raised."""

    def __init__(self, file: Any, report: ReadReport, name: str) -> None:
        super().__init__(file)
        self._report, self._name = report, name

    def _parse_line(self, line: str) -> can.Message | None:
        try:
            msg = self._parse_cols(tuple(line.split(maxsplit=self._num_columns)))
        except (ValueError, IndexError, KeyError, TypeError) as exc:
            self._report.skip(self._name, f"bad TRC line {line.strip()[:40]!r} ({exc})")
            return None
        if msg is None:
            self._report.skip(self._name, f"not a TRC frame {line.strip()[:40]!r}")
        return msg


def _csv_frames(lines: Iterable[str], name: str, report: ReadReport) -> Iterator[Frame]:
    for number, line in enumerate(lines, 1):
        cells = line.strip().split(",")
        if number == 1 and cells[:1] == ["timestamp"]:
            continue
        if cells == [""]:
            continue
        try:
            ts, ident, ext, remote, error, dlc, data = cells
            payload = bytes(int(dlc)) if remote == "1" else base64.b64decode(data, validate=True)  # as .log: the DLC
            frame = Frame(float(ts), int(ident, 16) & 0x1FFFFFFF, payload, None, ext == "1", remote == "1", error == "1")
        except (ValueError, binascii.Error) as exc:
            report.skip(f"{name}:{number}", f"not a python-can CSV row ({exc})")
            continue
        yield frame


def _library_frames(reader: Any, name: str, report: ReadReport) -> Iterator[Frame]:
    count = 0
    try:
        for msg in reader:
            count += 1
            yield Frame.from_message(msg)
    except Exception as exc:  # a corrupt or truncated file ends the read, reported
        report.problems.append(f"{name}: unreadable after {count} frame(s), the rest is lost "
                               f"(truncated or corrupt: {type(exc).__name__}: {str(exc)[:80] or 'no detail'})")
    finally:
        try:
            reader.stop()
        except Exception:  # noqa: S110 - closing a reader that already failed
            pass
    if isinstance(reader, can.BLFReader):
        size = Path(name).stat().st_size
        if reader.file_size and size < reader.file_size:
            report.problems.append(f"{name}: truncated: {size} of the {reader.file_size} bytes its header announces")
        elif reader.object_count and count < reader.object_count:
            report.problems.append(f"{name}: {count} of the {reader.object_count} frames its header announces")


def _open_library_reader(path: Path, suffix: str, report: ReadReport) -> Any:
    name = str(path)
    try:
        if suffix == ".asc":
            return _ASCReader(name, report, name)
        if suffix == ".trc":
            return _TRCReader(name, report, name)
        if suffix == ".blf":
            return can.BLFReader(name)
        if importlib.util.find_spec("asammdf") is None:
            raise TraceError(f"{name}: reading .mf4 needs asammdf (pip install asammdf)")
        return can.MF4Reader(name)
    except TraceError:
        raise
    except Exception as exc:
        raise TraceError(f"{name}: not a valid {suffix} file ({type(exc).__name__}: {str(exc)[:80]})") from None


def _text_lines(path: Path) -> TextIO:
    return path.open("r", encoding="utf-8", errors="replace", newline="")


def frames_of_file(path: str | Path, report: ReadReport, stdin: TextIO | None = None) -> Iterator[Frame]:
    """The frames of one trace file (``-``: candump's log format on standard input)."""
    if str(path) == "-":
        report.files.append("-")
        yield from _candump_frames(stdin or sys.stdin, "<stdin>", report)
        return
    path = _checked(path)
    suffix = trace_suffix(path)
    report.files.append(str(path))
    if suffix in (".log", ".csv"):
        parse = _candump_frames if suffix == ".log" else _csv_frames
        with _text_lines(path) as f:
            yield from parse(f, str(path), report)
        return
    yield from _library_frames(_open_library_reader(path, suffix, report), str(path), report)


def read_frames(paths: Iterable[str | Path], report: ReadReport, stdin: TextIO | None = None, *,
                require_frames: bool = False) -> Iterator[Frame]:
    """The frames of several files, one after the other, counted (and backwards timestamps) in ``report``.
    ``require_frames``: a file without a single readable frame (empty, not a trace, another format
    under this suffix) ends the read with a :class:`TraceError` saying what was wrong and where."""
    last = float("-inf")
    for path in paths:
        before = report.frames
        for frame in frames_of_file(path, report, stdin):
            report.frames += 1
            if frame.timestamp < last:
                report.backwards += 1
            last = frame.timestamp
            yield frame
        if require_frames and report.frames == before:
            raise TraceError(no_frames_reason(path, report))


def check_has_frames(paths: Iterable[str | Path]) -> None:
    """Fail early, with one line, for a file that holds no readable frame (read up to its first one)."""
    for path in paths:
        if str(path) != "-":
            frames = read_frames([path], ReadReport(), require_frames=True)
            try:
                next(frames, None)
            finally:
                frames.close()


def no_frames_reason(path: str | Path, report: ReadReport) -> str:
    """One line: why ``path`` gave no frame."""
    name = "<stdin>" if str(path) == "-" else str(path)
    kind = "standard input" if str(path) == "-" else f"a {trace_suffix(path)} trace"
    try:
        empty = str(path) != "-" and Path(path).stat().st_size == 0
    except OSError:
        empty = False
    if empty:
        why = "the file is empty"
    else:
        mine = [p for p in report.problems if p.startswith(f"{name}:")]
        skipped = [e for e in report.examples if e.startswith(f"{name}")]
        if mine:
            why = mine[-1][len(name) + 2:]
            if "(truncated or corrupt: " in why:  # no frame at all: the reader's own complaint is the reason
                why = why.split("(truncated or corrupt: ", 1)[1].rstrip(")")
        elif skipped:
            why = f"no line is a frame, e.g. {skipped[0][len(name):].lstrip(':')}"
        else:
            why = "nothing in it is a frame"
    return f"{name}: no CAN frame could be read ({why}): is it {kind}?"


def trace_suffix(path: str | Path) -> str:
    """The format's suffix of ``path``, lower case: a file still being written by the session
    recorder (``NAME.log.part``, or left so by a recorder that was killed) is read as its format."""
    p = Path(path)
    if p.suffix.lower() == ".part" and Path(p.stem).suffix:
        return Path(p.stem).suffix.lower()
    return p.suffix.lower()


def _checked(path: str | Path) -> Path:
    p = Path(path)
    if trace_suffix(p) not in READ_SUFFIXES:
        raise TraceError(f"{p}: unknown trace format {p.suffix or '(no suffix)'!r}; readable: {', '.join(READ_SUFFIXES)}")
    if p.is_dir():
        raise TraceError(f"{p}: is a folder, not a trace file")
    if not p.is_file():
        raise TraceError(f"{p}: no such file")
    return p


def check_readable(paths: Iterable[str | Path]) -> None:
    """Fail early, with one line, for a missing file or a format we cannot read."""
    for path in paths:
        if str(path) != "-":
            _checked(path)

"""Safe outputs: the one way aider-exo writes a file a user asked for.

Every output is checked before any work is done (:func:`check_output`) and written under a
temporary name in its own folder, flushed to disk and renamed onto its name only once complete
(:func:`atomic_path`, :func:`atomic_write`, :func:`write_bytes`, :func:`write_text`), so an
interrupted run, a full disk or a bad input never leaves a partly written file under the name asked
for, and never replaces a file with half of another. An output that is one of the command's own
inputs is refused, as are a missing folder and a folder given for a file; every error is one line
naming the path (:class:`OutputError`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from config.errors import AiderError

__all__ = ["OutputError", "atomic_path", "atomic_write", "check_output", "check_output_folder", "same_file",
           "write_bytes", "write_text"]

PathLike = str | os.PathLike[str]


class OutputError(AiderError):
    """An output that cannot or must not be written (one line, naming the path)."""


def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether ``a`` and ``b`` name the same file (resolved paths, or the same inode when both exist)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.resolve() == pb.resolve():
            return True
    except (OSError, RuntimeError):
        pass
    try:
        return os.path.samefile(pa, pb)
    except OSError:
        return False


def check_output(path: PathLike, *, inputs: Iterable[PathLike | None] = (), option: str | None = None) -> Path:
    """Refuse, before any work, an output that is a folder, lies in a missing folder, or is the same
    file as one of ``inputs`` (``-`` and None inputs are ignored). ``option`` (``-o``) names it in
    the message. Returns ``path`` as a :class:`Path`."""
    path = Path(path)
    name = f"{option} {path}" if option else str(path)
    if path.is_dir():
        raise OutputError(f"{name}: is a folder; give a file name")
    parent = path.parent
    if not parent.is_dir():
        what = "is not a folder" if parent.exists() else "no such folder"
        raise OutputError(f"{name}: {parent}: {what} (create it first)")
    for given in inputs:
        if given is None or str(given) == "-":
            continue
        if same_file(path, given):
            raise OutputError(f"{name}: is the input {given}; it would be overwritten: write to another file")
    return path


def check_output_folder(path: PathLike, *, create: bool = True, parents: bool = False, option: str | None = None) -> Path:
    """An output folder: refuse a file of that name; create it (``parents``: and its parents, else
    the parent must exist). Returns it as a :class:`Path`."""
    path = Path(path)
    name = f"{option} {path}" if option else str(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{name}: is a file, not a folder")
    if not path.is_dir():
        if not parents and not path.parent.is_dir():
            raise OutputError(f"{name}: {path.parent}: no such folder (create it first)")
        if create:
            try:
                path.mkdir(parents=parents, exist_ok=True)
            except OSError as exc:
                raise OutputError(f"{name}: cannot create the folder ({exc.strerror or exc})") from None
    return path


def _umask() -> int:
    try:  # read without changing it (os.umask sets it, for every thread)
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _os_error(path: Path, exc: OSError) -> OutputError:
    where = exc.filename if exc.filename is not None and not Path(os.fsdecode(exc.filename)).name.startswith(f".{path.name}.") else path
    return OutputError(f"{where}: cannot write ({exc.strerror or exc})")


@contextmanager
def atomic_path(path: PathLike, *, inputs: Iterable[PathLike | None] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` to write; when the block ends normally the file is
    flushed to disk and renamed onto ``path``, when it raises (or is interrupted) it is removed and
    ``path`` is untouched. An OS error is an :class:`OutputError` naming the path."""
    path = check_output(path, inputs=inputs)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:  # mkstemp's file is private (0600): give it the mode a plain open() would have
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)
    except OSError as exc:
        raise _os_error(path, exc) from None
    tmp = Path(name)
    try:
        yield tmp
        if tmp.exists():
            _fsync(tmp)
            os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _os_error(path, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write(path: PathLike, write: Callable[[IO[bytes]], object], *, inputs: Iterable[PathLike | None] = ()) -> Path:
    """Call ``write(file)`` on a temporary file beside ``path`` opened for binary writing, then
    flush it to disk and rename it onto ``path`` (see :func:`atomic_path`). Returns ``path``."""
    with atomic_path(path, inputs=inputs) as tmp, open(tmp, "wb") as f:
        write(f)
    return Path(path)


def write_bytes(path: PathLike, data: bytes, *, inputs: Iterable[PathLike | None] = ()) -> Path:
    return atomic_write(path, lambda f: f.write(data), inputs=inputs)


def write_text(path: PathLike, text: str, *, inputs: Iterable[PathLike | None] = (), encoding: str = "utf-8") -> Path:
    return write_bytes(path, text.encode(encoding), inputs=inputs)

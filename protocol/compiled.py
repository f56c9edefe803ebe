"""The per-tick numerics compiled with Cython, and the choice at import between them and their source.

Each module of :data:`MODULES` is plain Python whose C types are annotations (``import cython``:
Cython's pure-Python mode; a ``.pxd`` beside it would count as part of its source), so the same
source runs interpreted or compiled. The build
(``setup.py``) compiles them when Cython and a C compiler are there and writes, beside each
extension, ``<module>.sha256``: the SHA-256 of the source it was compiled from. At import a module
is loaded compiled unless

* ``AIDER_EXO_PURE_PYTHON`` is set (to anything but ``0`` or empty): the interpreted reference,
  which the tests compare the compiled walk against;
* there is no extension (installed without a compiler);
* the extension was built from another source (an edited checkout not rebuilt: ``make`` or
  ``pip install -e .`` rebuilds it): then the source runs, and the first such import says so once
  on stderr.

An extension beside a module of the project's packages that is not in :data:`MODULES` (one
compiled once, since taken off the list) is never loaded: its source runs.

:func:`install` puts the chooser on ``sys.meta_path`` (this module's import does; every package
that holds one of the modules imports it in its ``__init__``). :func:`report` says how each module
is loaded (``aider-exo --version``).
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
from pathlib import Path

#: the compiled modules, by the profile of a walking tick (docs/PERFORMANCE.md)
MODULES = (
    "controller.balance",
    "controller.distribution",
    "controller.estimator",
    "protocol.codec_kernel",
    "sim.balance",
    "protocol.codec",
    "protocol.e2e",
)
PACKAGES = ("config", "controller", "nodes", "protocol", "sim", "tools")  # the project's top-level packages
PURE_ENV = "AIDER_EXO_PURE_PYTHON"
SIDECAR = ".sha256"


def pure_python() -> bool:
    """Whether the interpreted reference is asked for."""
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def source_digest(source: Path) -> str:
    """The SHA-256 of a module's source and of the ``.pxd`` beside it (its C types), as the build records it."""
    h = hashlib.sha256(source.read_bytes())
    pxd = source.with_suffix(".pxd")
    if pxd.is_file():
        h.update(pxd.read_bytes())
    return h.hexdigest()


def _extension(folder: Path, leaf: str) -> Path | None:
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / f"{leaf}{suffix}"
        if path.is_file():
            return path
    return None


class _Chooser:
    """A meta path finder for the project's modules: the source where an extension beside it is
    not to be used, else nothing (the standard finder loads the module: the extension, which it
    prefers to the source, or the source alone)."""

    def __init__(self) -> None:
        self.why: dict[str, str] = {}  # module -> why it runs interpreted
        self._warned = False

    def find_spec(self, fullname: str, path, target=None):
        if not path or fullname.partition(".")[0] not in PACKAGES:
            return None
        leaf = fullname.rpartition(".")[2]
        for entry in path:
            source = Path(entry) / f"{leaf}.py"
            if source.is_file():
                break
        else:
            return None
        if fullname in MODULES:
            why = self._interpreted_because(source, leaf)
        else:
            why = None if _extension(source.parent, leaf) is None else "not in protocol/compiled.py's MODULES"
        if why is None:
            return None
        self.why[fullname] = why
        return importlib.util.spec_from_file_location(fullname, source)

    def _interpreted_because(self, source: Path, leaf: str) -> str | None:
        if pure_python():
            return f"{PURE_ENV} is set"
        if _extension(source.parent, leaf) is None:
            return "not compiled (no C compiler or Cython at install)"
        recorded = source.parent / f"{leaf}{SIDECAR}"
        if recorded.is_file() and recorded.read_text().strip() == source_digest(source):
            return None
        if not self._warned:
            self._warned = True
            print(f"aider-exo: warning: {source} changed since it was compiled; running it interpreted "
                  "(rebuild: make, or pip install -e .)", file=sys.stderr)
        return "compiled from another source (rebuild: make)"


_CHOOSER = _Chooser()


def install() -> None:
    """Put the chooser first on ``sys.meta_path`` (once)."""
    if _CHOOSER not in sys.meta_path:
        sys.meta_path.insert(0, _CHOOSER)


def report() -> dict[str, str]:
    """Each compiled module: ``compiled`` or why it runs interpreted, as an import would load it
    (found, not imported: a module of an extra that is not installed is reported too)."""
    install()
    out = {}
    for name in MODULES:
        spec = importlib.util.find_spec(name)
        compiled = spec is not None and (spec.origin or "").endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))
        out[name] = "compiled" if compiled else _CHOOSER.why.get(name, "interpreted")
    return out

install()

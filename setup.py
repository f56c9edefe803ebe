"""Build: the package as pyproject.toml says, with the per-tick numerics of protocol/compiled.py's
MODULES compiled by Cython (pure-Python mode: the annotated .py itself) where a C compiler is there.

Without Cython or a compiler the package installs and runs interpreted, and the build says so
once. Each extension gets a ``<module>.sha256`` beside it, the digest of the source it was built
from: at import an extension whose source has changed since is not used (protocol/compiled.py)."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.errors import CCompilerError, ExecError, PlatformError

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("_aider_compiled", HERE / "protocol" / "compiled.py")
compiled = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compiled)  # the list and the digest without importing the package
sys.meta_path.remove(compiled._CHOOSER)  # (its import put the chooser on the build's own path)

#: no contraction of a * b + c into one fused instruction: the compiled arithmetic rounds as the
#: interpreter's does, so a compiled walk is bit-identical to the interpreted one
CFLAGS = ["-O2", "-ffp-contract=off"]


def _warn(why: str) -> None:
    print(f"aider-exo build: warning: {why}; the per-tick numerics run interpreted "
          "(make installs a C compiler and Python's headers: docs/PERFORMANCE.md)", file=sys.stderr)


def extensions() -> list[Extension]:
    try:
        from Cython.Build import cythonize
    except ImportError:
        _warn("Cython is not installed")
        return []
    modules = [Extension(name, [name.replace(".", "/") + ".py"], extra_compile_args=CFLAGS) for name in compiled.MODULES]
    return cythonize(modules, language_level=3, build_dir="build/cython", quiet=True, nthreads=os.cpu_count() or 1)


class BuildExt(build_ext):
    """build_ext that writes each extension's source digest beside it, and builds nothing (with a
    warning) where there is no compiler."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if self.parallel is None:
            self.parallel = os.cpu_count() or 1  # the extensions compile side by side

    def run(self) -> None:
        try:
            super().run()  # builds in the build folder, then copies into the source tree where in place (editable)
        except (CCompilerError, ExecError, PlatformError) as exc:  # no compiler, no Python headers
            _warn(f"the extensions could not be built ({type(exc).__name__}: {exc})")
            return
        for ext in self.extensions:
            target = Path(self.get_ext_fullpath(ext.name))  # in place or in the build folder, as installed
            source = HERE / (ext.name.replace(".", "/") + ".py")
            (target.parent / (ext.name.rpartition(".")[2] + compiled.SIDECAR)).write_text(compiled.source_digest(source) + "\n")


setup(ext_modules=extensions(), cmdclass={"build_ext": BuildExt})

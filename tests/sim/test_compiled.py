"""The per-tick numerics compiled with Cython (protocol/compiled.py): installed compiled where a C
compiler is, and a compiled walk bit-identical to the interpreted reference."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from protocol import compiled
from tests.conftest import IN_CI, ROOT
from tests.support.fingerprint import walk_fingerprint


def _compiler_problem() -> str | None:
    if shutil.which("cc") is None:
        return "no C compiler (cc)"
    if not (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file():
        return "no Python headers (Python.h)"
    return None


def test_every_numerics_module_runs_compiled_where_a_compiler_is():
    problem = _compiler_problem()
    if problem is not None:
        message = f"COMPILED NUMERICS NOT CHECKED: {problem}"
        if IN_CI:
            pytest.fail(message + " (CI=true requires them: make installs gcc and python3-dev)", pytrace=False)
        pytest.skip(message)
    assert compiled.report() == {name: "compiled" for name in compiled.MODULES}


def test_the_compiled_walk_is_the_interpreted_one_frame_for_frame_and_state_for_state():
    """A 3-cycle lock-step walk here (compiled where built) and in a process with
    ``AIDER_EXO_PURE_PYTHON`` (every module from its source): the same frames and states."""
    here, cycles = walk_fingerprint(cycles=3, seed=0)
    assert cycles == 3
    env = {**os.environ, compiled.PURE_ENV: "1"}
    out = subprocess.run([sys.executable, "-m", "tests.support.fingerprint", "3", "0"], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == [here, "3"], (compiled.report(), out.stdout)

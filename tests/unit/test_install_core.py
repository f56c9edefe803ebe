"""The controller-only install (`pip install .`, docs/DEPLOY.md): the controller, the protocol, the
configuration and the node firmware run in a venv that holds only pyproject's core dependencies, and
a command that needs an extra says which in one line.

The venv is real (``python -m venv``, the project installed from a wheel by pip) but offline: the
core dependencies and what they require are copied from this interpreter's installed distributions,
so nothing of the extras (pybullet, scipy, pillow, matplotlib, aiohttp, ray) can be there unless
pyproject's core asks for it.
"""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from tests.conftest import ROOT

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: the modules of the extras; none may be importable in the core venv
EXTRA_MODULES = ("pybullet", "scipy", "PIL", "matplotlib", "aiohttp", "ray", "playwright", "pytest")
ONE_LINE = re.compile(r"aider-exo: error: '(?P<command>[^']+)' needs the (?P<extra>\w+) extra \((?P<module>\w+) is not "
                      r"installed\): pip install 'aider-exo\[(?P=extra)\]'")


def _closure(requirements: list[str]) -> dict[str, md.Distribution]:
    """The installed distributions the requirements need, transitively, without any extra."""
    env = {**default_environment(), "extra": ""}
    found: dict[str, md.Distribution] = {}
    todo = [Requirement(r) for r in requirements]
    while todo:
        req = todo.pop()
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        name = canonicalize_name(req.name)
        if name in found:
            continue
        dist = md.distribution(req.name)
        assert req.specifier.contains(dist.version, prereleases=True), f"{req}: {dist.version} is installed"
        found[name] = dist
        todo.extend(Requirement(r) for r in dist.requires or [])
    return found


def _copy_installed(dist: md.Distribution, site: Path) -> None:
    """An installed distribution's files under site-packages (its scripts in bin/ are not needed)."""
    root = Path(dist.locate_file(""))
    for file in dist.files or []:
        if file.parts[0] == "..":
            continue
        src = root / file
        if src.is_file():
            dst = site / file
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)


def _builds_wheels() -> bool:
    from packaging.version import Version

    try:
        return Version(md.version("setuptools")) >= Version("70.1")
    except md.PackageNotFoundError:
        return False


@pytest.fixture(scope="module")
def core(tmp_path_factory):
    """A venv with the project and its core dependencies only: (bin folder, a working folder outside the checkout)."""
    tmp = tmp_path_factory.mktemp("core")
    venv = tmp / "v"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = next((venv / "lib").glob("python3.*/site-packages"))
    for dist in _closure(PYPROJECT["project"]["dependencies"]).values():
        _copy_installed(dist, site)
    # The project as pip installs it (package list, package data, console script), from a copy of the
    # working tree so that nothing is built inside the checkout.
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for top in {p.split(".")[0] for p in PYPROJECT["tool"]["setuptools"]["packages"]}:
        shutil.copytree(ROOT / top, src / top, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--quiet"]
    # The build backend as pyproject asks for it: this interpreter's setuptools when it builds wheels
    # itself (70.1 or newer), else setuptools>=68 from the index or pip's cache, as `pip install .` does.
    offline = ["--no-build-isolation", "--no-index"] if _builds_wheels() else []
    subprocess.run([*pip, "wheel", "--no-deps", *offline, "-w", str(tmp / "wheels"), str(src)], check=True, cwd=tmp)
    wheel = next((tmp / "wheels").glob("aider_exo-*.whl"))
    subprocess.run([*pip, "--python", str(venv / "bin" / "python"), "install", "--no-deps", "--no-index", str(wheel)],
                   check=True, cwd=tmp)
    work = tmp / "work"
    work.mkdir()
    return venv / "bin", work


def _run(core, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    bin_, work = core
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PYTHONNOUSERSITE"] = "1"
    cmd = [str(bin_ / argv[0]), *argv[1:]]
    return subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)


def test_the_core_venv_has_none_of_the_extras_and_imports_the_controller_from_the_install(core):
    code = (
        "import importlib, importlib.util, json, pkgutil\n"
        f"absent = [m for m in {EXTRA_MODULES!r} if importlib.util.find_spec(m) is None]\n"
        "import config, controller, nodes.firmware, protocol\n"
        "mods = []\n"
        "for pkg in (config, controller, protocol):\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "        if not m.name.endswith('__main__'):\n"
        "            importlib.import_module(m.name)\n"
        "            mods.append(m.name)\n"
        "print(json.dumps({'absent': absent, 'controller': controller.__file__, 'modules': mods}))\n"
    )
    done = _run(core, "python", "-c", code)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    assert seen["absent"] == list(EXTRA_MODULES)
    assert "/site-packages/controller/" in seen["controller"]  # the install, not the checkout
    assert "controller.loop" in seen["modules"] and "protocol.bus" in seen["modules"]


def test_the_core_commands_run_without_the_extras(core):
    for argv in (["aider-exo", "--help"], ["aider-exo", "controller", "--help"], ["python", "-m", "controller", "--help"],
                 ["python", "-m", "nodes", "--help"], ["aider-exo", "trace", "decode", "--help"]):
        done = _run(core, *argv)
        assert done.returncode == 0 and done.stdout.startswith("usage: "), (argv, done.stderr)
    done = _run(core, "aider-exo", "protocol", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)
    done = _run(core, "aider-exo", "config", "check", str(ROOT / "config" / "default.yaml"))
    assert done.returncode == 0, done.stderr
    # The controller itself: real time on a virtual bus with no nodes, for half a second.
    done = _run(core, "aider-exo", "controller", "--bus", "virtual", "--channel", "core", "--ticks", "25", "--quiet", "--json")
    assert done.returncode == 0, done.stderr
    assert "stopped_by" in json.loads(done.stdout)


@pytest.mark.parametrize("argv, command, extra", [
    (["sim", "walk"], "aider-exo sim walk", "sim"),
    (["nodes", "--bus", "virtual", "--channel", "core"], "aider-exo nodes", "sim"),
    (["walk", "--steps", "1"], "aider-exo walk", "sim"),
    (["view", "--trace", "missing.log"], "aider-exo view", "view"),
])
def test_a_command_that_needs_a_missing_extra_says_which_in_one_line(core, argv, command, extra):
    done = _run(core, "aider-exo", *argv)
    assert done.returncode == 1, done.stderr
    line = done.stderr.strip()
    assert "\n" not in line, line
    match = ONE_LINE.fullmatch(line)
    assert match, line
    assert (match["command"], match["extra"]) == (command, extra)


def test_the_cli_names_the_extra_that_pyproject_installs_each_module_with():
    """tools.cli.EXTRAS against pyproject's extras: each module's distribution is in the extra named."""
    from tools.cli import EXTRAS

    extras = {name: {canonicalize_name(Requirement(r).name) for r in reqs}
              for name, reqs in PYPROJECT["project"]["optional-dependencies"].items()}
    core_deps = {canonicalize_name(Requirement(r).name) for r in PYPROJECT["project"]["dependencies"]}
    providers = md.packages_distributions()
    named = set()
    for module, extra in EXTRAS.items():
        dists = {canonicalize_name(d) for d in providers.get(module, [module])}
        assert dists & extras[extra], f"{module} ({dists}) is not in the {extra} extra"
        assert not dists & core_deps, f"{module} is a core dependency"
        named |= dists & extras[extra]
    runtime = set().union(*(deps for name, deps in extras.items() if name not in ("test", "all")))
    assert runtime == named, f"in an extra but not in tools.cli.EXTRAS: {runtime - named}"


def test_the_core_install_runs_the_numerics_compiled_where_a_compiler_is(core):
    """The wheel `pip install .` builds carries the compiled numerics (protocol/compiled.py) and their
    source digests; `aider-exo --version` says how each runs."""
    import sysconfig

    from protocol.compiled import MODULES

    done = _run(core, "aider-exo", "--version")
    assert done.returncode == 0, done.stderr
    compilable = shutil.which("cc") is not None and (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file()
    want = len(MODULES) if compilable else 0
    assert f"compiled numerics: {want} of {len(MODULES)} modules" in done.stdout, done.stdout

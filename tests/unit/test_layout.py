"""Project layout rules: import directions, explicit packaging, one CLI module per subcommand."""

from __future__ import annotations

import ast
import tomllib

import pytest

from tests.conftest import ROOT

CODE_FOLDERS = ["config", "controller", "nodes", "protocol", "sim", "tools"]

# package -> top-level packages it must never import
FORBIDDEN = {
    "controller": {"sim", "nodes", "pybullet"},
    "sim": {"controller"},
    "protocol": {"controller", "nodes", "sim", "pybullet"},
    "config": {"controller", "nodes", "sim", "protocol", "tools", "pybullet"},
}


def _imports(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module.split(".")[0]


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_import_direction(package):
    bad = []
    for path in (ROOT / package).rglob("*.py"):
        for name in _imports(path):
            if name in FORBIDDEN[package]:
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad


def test_every_code_folder_is_an_explicit_package_and_tests_are_not():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = set(project["tool"]["setuptools"]["packages"])
    for folder in CODE_FOLDERS:
        for init in (ROOT / folder).rglob("__init__.py"):
            name = ".".join(init.parent.relative_to(ROOT).parts)
            assert name in packages, f"{name} is missing from pyproject's package list"
    assert not any(p.split(".")[0] == "tests" for p in packages)
    for folder in CODE_FOLDERS:
        assert (ROOT / folder / "__init__.py").exists()


def test_one_module_per_subcommand():
    from tools.cli import SUBCOMMANDS

    for name, module in SUBCOMMANDS.items():
        assert module == f"tools.cli.{name}"
        assert (ROOT / "tools" / "cli" / f"{name}.py").exists()


def test_time_is_read_only_through_the_clock_module():
    offenders = []
    for folder in CODE_FOLDERS:
        for path in (ROOT / folder).rglob("*.py"):
            if path.name == "clock.py":
                continue
            text = path.read_text()
            for call in ("time.time(", "time.monotonic(", "time.sleep(", "time.perf_counter("):
                if call in text:
                    offenders.append(f"{path.relative_to(ROOT)}: {call}")
    assert not offenders


def test_the_tick_is_defined_once_in_the_clock_module():
    """protocol/clock.py names the tick (TICK_MS, TICK_S, TICK_NS); no other module defines one of
    its own or writes the tick's seconds (0.02) as a literal beside a tick count."""
    offenders = []
    for folder in CODE_FOLDERS + ["tests"]:
        for path in (ROOT / folder).rglob("*.py"):
            if path == ROOT / "protocol" / "clock.py":
                continue
            tree = ast.parse(path.read_text(), filename=str(path))
            for node in ast.walk(tree):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
                offenders += [f"{path.relative_to(ROOT)}:{node.lineno} defines {t.id}" for t in targets
                              if isinstance(t, ast.Name) and t.id.startswith("TICK_")]
                if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
                    names = [ast.unparse(side) for side in (node.left, node.right)]
                    if any(isinstance(side, ast.Constant) and side.value == 0.02 for side in (node.left, node.right)) \
                            and any("tick" in n.lower() for n in names):
                        offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} {ast.unparse(node)}")
    assert not offenders, offenders


# The controller's core sees typed data only (controller/interfaces.py); from protocol/ these
# modules of enums and records, nothing about frames (catalog, codec, counters, clock).
CORE_PROTOCOL_IMPORTS = {"protocol.enums", "protocol.commands"}


def test_the_controller_core_knows_no_frame():
    """controller/core.py imports from protocol/ only its typed data, and names no message or
    signal of the DBC: the hardware (controller/cansystem.py, controller/hardware.py) maps them."""
    from protocol.catalog import default_catalog

    path = ROOT / "controller" / "core.py"
    tree = ast.parse(path.read_text(), filename=str(path))
    modules = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    modules |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert {m for m in modules if m.split(".")[0] == "protocol"} <= CORE_PROTOCOL_IMPORTS, modules
    catalog = default_catalog()
    names = {m.name for m in catalog.messages} | {s.name for m in catalog.messages for s in m.signals}
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    assert not names & strings, names & strings


def test_no_controller_module_is_over_400_lines():
    long = {p.name: n for p in (ROOT / "controller").rglob("*.py") if (n := len(p.read_text().splitlines())) > 400}
    assert not long, long


def test_test_modules_import_no_other_test_module():
    """Shared test helpers live in tests/support (and the fixtures in tests/conftest.py); a test
    module never imports another one."""
    offenders = []
    for path in (ROOT / "tests").rglob("test_*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tests."):
                if not node.module.startswith(("tests.support.", "tests.conftest")):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} from {node.module}")
    assert not offenders, offenders


def test_every_test_module_is_in_the_folder_of_its_kind():
    """tests/unit (no physics, no real bus), tests/sim (PyBullet walks), tests/bus (transports,
    processes on a bus, the view), tests/realtime (the wall clock alone), tests/support (helpers)."""
    kinds = {"unit", "sim", "bus", "realtime"}
    modules = list((ROOT / "tests").rglob("test_*.py"))
    assert modules and all(p.parent.parent == ROOT / "tests" and p.parent.name in kinds for p in modules), \
        [str(p.relative_to(ROOT)) for p in modules if p.parent.name not in kinds]
    assert not list((ROOT / "tests" / "support").glob("test_*.py"))

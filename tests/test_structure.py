"""The house: imports only point down the layers, and the pure step reads no clock."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

from agent.control import Controller, ControlParams, StepInput

ROOT = Path(__file__).resolve().parents[1]

# package -> the project packages it may import (anything not listed is forbidden)
ALLOWED = {
    "geometry": set(),
    "wire": {"geometry"},
    "runtime": {"geometry", "wire"},
    "leader": {"geometry", "wire"},
    "scenario": {"geometry", "wire"},  # the one name rule is the key space's (wire.keys)
    "agent": {"geometry", "leader", "scenario", "wire", "runtime"},
    "camera_service": {"geometry", "scenario", "wire"},
    "simulator": {"geometry", "agent", "leader", "scenario", "wire", "runtime", "camera_service", "viewer"},
    "viewer": {"geometry", "scenario", "wire"},  # scenario: a load's placement (scenario.cargo)
    "experiments": {"geometry", "agent", "leader", "scenario", "wire", "runtime", "camera_service",
                    "simulator", "viewer"},
    "deploy": {"geometry", "agent", "leader", "scenario", "wire", "runtime"},
    "scenarios": set(),  # data: the shipped scenario files
}
PROJECT = set(ALLOWED) | {"formation"}


@functools.cache
def _tree(path: Path) -> ast.Module:
    """The syntax tree of the file at ``path``, parsed once for every check here."""
    return ast.parse(path.read_text(encoding="utf-8"))


def _modules(path: Path) -> set[str]:
    """Every module imported anywhere in ``path`` (lazy imports included)."""
    found = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found.update(names)
    return found


def _imports(path: Path) -> set[str]:
    """Top-level project packages imported anywhere in ``path``."""
    return {m.split(".")[0] for m in _modules(path)} & PROJECT


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_a_package_imports_only_the_layers_below_it(package: str) -> None:
    bad = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = str(path.relative_to(ROOT))
        up = _imports(path) - ALLOWED[package] - {package}
        if up:
            bad[rel] = sorted(up)
    assert not bad, f"imports running up the layers: {bad}"


def test_product_code_does_not_import_the_test_helpers() -> None:
    users = [str(p.relative_to(ROOT)) for pkg in PROJECT for p in sorted((ROOT / pkg).rglob("*.py"))
             if "runtime.testing" in _modules(p)]
    assert users == []


def test_the_control_step_reads_no_clock_unless_given_one() -> None:
    pure = Controller(ControlParams()).step(StepInput((0.0, 0.0, 0.0), (1.0, 0.5)))
    assert pure.solve_us == 0.0
    ticks = iter([1_000, 6_000])
    timed = Controller(ControlParams(), clock=lambda: next(ticks)).step(
        StepInput((0.0, 0.0, 0.0), (1.0, 0.5)))
    assert timed.solve_us == pytest.approx(5.0)
    assert (timed.ux, timed.uy) == (pure.ux, pure.uy)


def test_step_inputs_carry_the_view_the_stall_and_switch_ellipses_for_pairs_in_all_to_all() -> None:
    # members and foreign robots are separation partners; the ellipses stay hazards in both
    # topologies (tie-break and the formation QP)
    from agent.control import Stall
    from agent.inputs import step_inputs
    from geometry.ellipse import Ellipse

    own = Ellipse(0.0, 0.0, 0.0, 0.6, 0.3)  # still, far from its goal: the stall clock runs
    other = Ellipse(3.0, 0.0, 0.0, 0.6, 0.3)
    reduced = step_inputs([(0.1, 0.2, 0.0, 0.0, 0.5)], own, "F1", (5.0, 0.0), [("F2", other)],
                          Stall(), 0.05, members=[(0.1, 0.2, 0.0, 0.0, 0.3), (0.6, 0.2, 0.0, 0.0, 0.0)])
    assert reduced.neighbours[0].df == 0.5 and reduced.others == [other] and reduced.pairwise == []
    assert [(q.x, q.theta) for q in reduced.partners] == [(0.1, 0.3), (0.6, 0.0)]
    assert reduced.hazards == [other]
    assert reduced.view is not None and reduced.view.other_names == ("F2",)
    assert reduced.view.name == "F1" and reduced.stall.still > 0.0

    a2a = step_inputs([], own, "F1", (5.0, 0.0), [("F2", other)], Stall(), 0.05,
                      foreign=[(3.0, 0.1, 0.0, 0.0, 1.0)])
    assert a2a.others == [] and [(p.x, p.y, p.df) for p in a2a.pairwise] == [(3.0, 0.1, 0.0)]
    assert [(q.x, q.theta) for q in a2a.partners] == [(3.0, 1.0)] and a2a.hazards == [other]

    blind = step_inputs([], None, "F1", (5.0, 0.0), [], Stall(1.0), 0.05)
    assert blind.view is None and blind.stall == Stall(1.0)


@pytest.mark.integration
def test_an_agent_whose_open_fails_half_way_still_closes_its_session(monkeypatch) -> None:
    import asyncio

    from agent import node as node_mod
    from agent import transport as transport_mod
    from agent.config import ZenohSettings, build_agent_configs
    from scenario import load_scenario

    scenario = load_scenario(ROOT / "scenarios" / "thesis-5.2.2.yaml")
    cfg = build_agent_configs(scenario, zenoh=ZenohSettings(mode="peer"))["r1"]
    node = node_mod.AgentNode(cfg, node_mod.NodeOptions(lockstep=True))
    opened = []
    real_open = node_mod.zenoh.open

    def spy(conf):
        session = real_open(conf)
        opened.append(session)
        return session

    def declare_fails(*_args, **_kwargs):
        raise RuntimeError("declare failed")

    monkeypatch.setattr(node_mod.zenoh, "open", spy)
    monkeypatch.setattr(transport_mod, "CountingPublisher", declare_fails)
    with pytest.raises(RuntimeError, match="declare failed"):
        asyncio.run(node.run(asyncio.Event()))
    assert len(opened) == 1 and node.transport is None


@pytest.mark.integration
def test_the_code_passes_the_linter_with_its_complexity_limit() -> None:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]


@pytest.mark.integration
def test_the_package_code_type_checks() -> None:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _import_targets(path: Path, known: set[str]) -> set[str]:
    """The project modules ``path`` imports, anywhere in it (lazy and type-checking imports
    included): ``from pkg import name`` is the submodule when ``name`` is one, relative imports
    resolved against the file's package."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, *([base] if base else [])])
            found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                         for a in node.names)
    return (found & known) - {name}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = _pop_component(stack, on_stack, v)
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _pop_component(stack: list[str], on_stack: set[str], root: str) -> list[str]:
    """Tarjan's step: the modules on ``stack`` down to ``root``, taken off it."""
    comp = []
    while True:
        w = stack.pop()
        on_stack.discard(w)
        comp.append(w)
        if w == root:
            return comp


def _project_files() -> list[Path]:
    return [p for pkg in sorted(PROJECT) for p in sorted((ROOT / pkg).rglob("*.py"))]


def test_no_two_project_modules_import_each_other_in_a_circle() -> None:
    files = _project_files()
    known = {_module_name(p) for p in files}
    graph = {_module_name(p): _import_targets(p, known) for p in files}
    assert _cycles(graph) == []


def test_the_circle_check_finds_a_circle_through_lazy_relative_and_from_imports() -> None:
    # the check itself: a -> b (from pkg import b), b -> c (relative), c -> a (lazy, in a function)
    graph = {"pkg.a": {"pkg.b"}, "pkg.b": {"pkg.c"}, "pkg.c": {"pkg.a"}, "pkg.d": {"pkg.a"}}
    assert _cycles(graph) == [["pkg.a", "pkg.b", "pkg.c"]]
    path = ROOT / "agent" / "inputs.py"  # `from . import unicycle`, `from .control import ...`
    known = {_module_name(p) for p in _project_files()}
    assert {"agent.unicycle", "agent.control", "agent.barriers"} <= _import_targets(path, known)


# --- no module reads another module's private names ------------------------------------------

PRIVATE_SCOPE = sorted(PROJECT | {"benchmarks", "tests"})
# Names with a leading underscore that are public all the same, each with the reason
PUBLIC_UNDERSCORED = {
    "_replace": "namedtuple's documented API (the underscore keeps it apart from field names)",
    "_asdict": "namedtuple's documented API",
    "_fields": "namedtuple's documented API",
    "_make": "namedtuple's documented API",
}
PUBLIC_MODULE_UNDERSCORED = {
    ("os", "_exit"): "documented: leave the process at once, without cleanup (a forked child)",
}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_reads(source: str | ast.Module) -> list[tuple[int, str]]:
    """(line, what) for each read of another module's private name in ``source``: ``from m
    import _x``, and ``obj._x`` on anything but ``self`` and ``cls`` (a module, another object,
    a call's result), unless the name is public all the same (:data:`PUBLIC_UNDERSCORED`)."""
    found = []
    tree = ast.parse(source) if isinstance(source, str) else source
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            found += [(node.lineno, f"from {'.' * node.level}{node.module or ''} import {a.name}")
                      for a in node.names if _private(a.name)]
        elif isinstance(node, ast.Attribute) and _private(node.attr):
            owner = node.value
            if isinstance(owner, ast.Name) and (
                    owner.id in ("self", "cls") or (owner.id, node.attr) in PUBLIC_MODULE_UNDERSCORED):
                continue
            if node.attr not in PUBLIC_UNDERSCORED:
                found.append((node.lineno, f"{ast.unparse(owner)[:40]}.{node.attr}"))
    return found


def test_no_module_reads_another_modules_private_names() -> None:
    found = [f"{path.relative_to(ROOT)}:{line}: {what}"
             for pkg in PRIVATE_SCOPE for path in sorted((ROOT / pkg).rglob("*.py"))
             for line, what in private_reads(_tree(path))]
    assert found == [], f"{len(found)} reads of private names:\n" + "\n".join(found)


def test_the_private_name_check_finds_imports_modules_and_objects_but_not_self() -> None:
    source = """
from m import _x, y
from . import _sibling
import os
def f(obj, other):
    os._exit(0)
    obj._y
    other.part._z
    make()._w
    point._replace(x=1)
class C:
    def g(self):
        return self._a, cls._b, super()._c
"""
    assert [what for _line, what in private_reads(source)] == [
        "from m import _x", "from . import _sibling", "obj._y", "other.part._z", "make()._w",
        "super()._c"]

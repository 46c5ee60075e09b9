"""The house: imports only point down the layers, and the pure step reads no clock."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from agent.control import ControlParams, control_step

ROOT = Path(__file__).resolve().parents[1]

# package -> the project packages it may import (anything not listed is forbidden)
ALLOWED = {
    "geometry": set(),
    "wire": {"geometry", "scenario"},  # wire.acl reads a scenario for its command line
    "leader": {"geometry", "wire"},
    "scenario": {"geometry"},
    "agent": {"geometry", "leader", "scenario", "wire"},
    "camera_service": {"geometry", "scenario", "wire"},
    "simulator": {"geometry", "agent", "leader", "scenario", "wire", "camera_service"},
    "experiments": {"geometry", "agent", "leader", "scenario", "wire", "camera_service", "simulator"},
    "deploy": {"geometry", "agent", "leader", "scenario", "wire"},
}
PROJECT = set(ALLOWED) | {"formation"}


def _modules(path: Path) -> set[str]:
    """Every module imported anywhere in ``path`` (lazy imports included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
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
        up = _imports(path) - ALLOWED[package] - {package}
        if up:
            bad[str(path.relative_to(ROOT))] = sorted(up)
    assert not bad, f"imports running up the layers: {bad}"


def test_product_code_does_not_import_the_test_helpers() -> None:
    users = [str(p.relative_to(ROOT)) for pkg in PROJECT for p in sorted((ROOT / pkg).rglob("*.py"))
             if "wire.testing" in _modules(p)]
    assert users == []


def test_the_control_step_reads_no_clock_unless_given_one() -> None:
    pure = control_step(ControlParams(), (0.0, 0.0, 0.0), (1.0, 0.5))
    assert pure.solve_us == 0.0
    ticks = iter([1_000, 6_000])
    timed = control_step(ControlParams(), (0.0, 0.0, 0.0), (1.0, 0.5), clock=lambda: next(ticks))
    assert timed.solve_us == pytest.approx(5.0)
    assert (timed.ux, timed.uy) == (pure.ux, pure.uy)

"""The scenarios the project ships (``scenarios/*.yaml``, package data of the wheel): found by
bare name, so ``formation sim thesis-5.2.2`` works from a checkout and from a ``pip install``.

The folder sits beside this package in both (the repository root, or ``site-packages``)."""

from __future__ import annotations

import os
from pathlib import Path

from .reader import ScenarioError

SHIPPED_DIR = Path(__file__).resolve().parent.parent / "scenarios"


def shipped_names() -> list[str]:
    """The names of the shipped scenarios (file names without ``.yaml``), sorted."""
    return sorted(p.stem for p in SHIPPED_DIR.glob("*.yaml"))


def _bare(p: Path) -> bool:
    """Whether ``p`` can name a shipped scenario: ``NAME``, ``NAME.yaml`` or ``scenarios/NAME``."""
    return len(p.parts) == 1 or (len(p.parts) == 2 and p.parts[0] == "scenarios")


def resolve(path: str | Path) -> Path:
    """``path`` itself when it exists or names a folder; else the shipped scenario it names
    (``thesis-5.2.2``, ``thesis-5.2.2.yaml`` or ``scenarios/thesis-5.2.2.yaml``), if any."""
    p = Path(path)
    if p.exists():
        return p
    candidate = SHIPPED_DIR / (p.name if p.suffix == ".yaml" else f"{p.name}.yaml")
    return candidate if _bare(p) and candidate.is_file() else p


def find(path: str | Path) -> Path:
    """:func:`resolve`, or one :class:`ScenarioError` line when there is nothing there: no such
    file, and, for a bare name, no shipped scenario of that name either (naming those there
    are)."""
    found = resolve(path)
    if os.path.lexists(found):
        return found
    if not _bare(Path(path)):
        raise ScenarioError(f"{path}: no such file")
    raise ScenarioError(f"{path}: no such file, nor a shipped scenario of that name (shipped: "
                        f"{', '.join(shipped_names())})")

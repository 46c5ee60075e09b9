"""Two output files compared byte for byte, a failure naming the first line where they part.

pytest's own report of two unequal byte strings is a diff of their whole reprs; of a
``robots.csv`` only its tail reaches a CI log, which shows neither where the files part nor
how. :func:`assert_same` says that in one line each, and a lock-step run's folder adds what its
``summary.json`` counted of late and missing inputs (:func:`lockstep_counts`).
"""

from __future__ import annotations

import json
from pathlib import Path

LOCKSTEP_COUNTS = (("agents", "lockstep_timeouts"), ("agents", "lockstep_catch_ups"),
                   ("agents", "stale"), ("world", "missing_cmds"))


def first_difference(a: Path, b: Path) -> str:
    """The first line where two text files differ ("" when none; a line count when one is the
    other's beginning)."""
    la = a.read_text(encoding="utf-8").splitlines()
    lb = b.read_text(encoding="utf-8").splitlines()
    for n, (x, y) in enumerate(zip(la, lb, strict=False), start=1):
        if x != y:
            return f"line {n}:\n  {a.parent.name}: {x}\n  {b.parent.name}: {y}"
    return f"{len(la)} lines against {len(lb)}" if len(la) != len(lb) else ""


def lockstep_counts(folder: Path) -> str:
    """A run folder's counts of late and missing lock-step inputs, from its ``summary.json``
    ("" when it has none)."""
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return ""
    found = [f"{part}.{name} {summary[part][name]}" for part, name in LOCKSTEP_COUNTS
             if isinstance(summary.get(part), dict) and name in summary[part]]
    return ", ".join(found)


def assert_same(a: Path, b: Path, what: str = "") -> None:
    """``a`` and ``b`` hold the same bytes; else AssertionError naming the first line where they
    part and each folder's lock-step counts."""
    if a.read_bytes() == b.read_bytes():
        return
    counts = [f"{p.parent.name}: {c}" for p in (a, b) if (c := lockstep_counts(p.parent))]
    raise AssertionError(f"{what or a.name} differs at {first_difference(a, b)}"
                         + ("\n  " + "; ".join(counts) if counts else ""))

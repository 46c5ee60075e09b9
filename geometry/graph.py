"""Formation graphs: who is adjacent to every other member (and so may lead).

Pure functions over robot names and edges; :mod:`scenario.succession` applies them to a
scenario's formations.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def can_lead(robots: Sequence[str], edges: Iterable[tuple[str, str]]) -> tuple[str, ...]:
    """Every robot of ``robots`` adjacent to all the others, in ``robots`` order."""
    adjacent: dict[str, set[str]] = {r: set() for r in robots}
    for i, j in edges:
        if i in adjacent and j in adjacent:
            adjacent[i].add(j)
            adjacent[j].add(i)
    return tuple(r for r in robots if adjacent[r] >= set(robots) - {r})


def successor(robots: Sequence[str], edges: Iterable[tuple[str, str]], leader: str) -> str | None:
    """The member that takes over when ``leader`` dies: the first robot other than ``leader``
    that can lead (:mod:`scenario.succession`), or None."""
    return next((r for r in can_lead(robots, edges) if r != leader), None)

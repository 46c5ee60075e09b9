"""Who takes the leader role when a formation's leader dies (fault containment, issue 14).

A leader must be adjacent to every other member of its formation (it hears every member's
``state`` to estimate the ellipse and sends each member ``others``). The members that are also
adjacent to every other member could lead as well; the *successor* is the first of them in the
formation's robot order (as written in the scenario), so every process that reads the same
scenario names the same one without talking. A formation whose graph has no such member has no
successor: ``formation check`` warns about it.

What the successor does (``agent.node``): it watches the leader's liveliness token
(:func:`leader_token_key`); when the token goes (the leader's session closed or its lease
expired), it takes the leader role for a formation that now stands still (its load hangs on the
dead robot): it publishes the formation's ellipse estimated from the members' positions with
zero velocity, exchanges ellipses with the other leaders and relays them to the members, so the
other formations keep avoiding it. When the leader's token comes back, it steps down.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from wire import keys

LEADER_TOKEN = "leader"  # liveliness: {prefix}/formation/{fid}/leader


def leader_token_key(prefix: str, formation: str) -> str:
    """The liveliness key the leader of ``formation`` holds while it runs."""
    return f"{keys.validate_prefix(prefix)}/formation/{keys.validate_id(formation, 'formation')}/" \
           f"{LEADER_TOKEN}"


def can_lead(robots: Sequence[str], edges: Iterable[tuple[str, str]]) -> tuple[str, ...]:
    """Every robot of ``robots`` adjacent to all the others, in ``robots`` order."""
    adjacent: dict[str, set[str]] = {r: set() for r in robots}
    for i, j in edges:
        if i in adjacent and j in adjacent:
            adjacent[i].add(j)
            adjacent[j].add(i)
    return tuple(r for r in robots if adjacent[r] >= set(robots) - {r})


def successor(robots: Sequence[str], edges: Iterable[tuple[str, str]], leader: str) -> str | None:
    """The member that takes over when ``leader`` dies, or None (see the module docstring)."""
    return next((r for r in can_lead(robots, edges) if r != leader), None)


def formation_successor(formation) -> str | None:
    """:func:`successor` of a :class:`scenario.model.FormationSpec`."""
    return successor(formation.robot_ids, ((e.i, e.j) for e in formation.edges), formation.leader)

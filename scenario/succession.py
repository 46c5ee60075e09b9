"""Who can take a formation's leader role, and who takes it when the leader dies.

A leader must be adjacent to every other member of its formation (it hears every member's
``state`` to estimate the ellipse and sends each member ``others``). The members that are also
adjacent to every other member could lead as well; the *successor* is the first of them in the
formation's robot order (as written in the scenario), so every process that reads the same
scenario names the same one without talking. A formation whose graph has no such member has no
successor: ``formation check`` warns about it. What the successor does is in
:mod:`leader.succession` and :mod:`agent.node`.
"""

from __future__ import annotations

from geometry.graph import can_lead, successor

from .model import FormationSpec

__all__ = ["can_lead", "formation_successor", "successor"]


def formation_successor(formation: FormationSpec) -> str | None:
    """:func:`successor` of a formation of the scenario."""
    return successor(formation.robot_ids, ((e.i, e.j) for e in formation.edges), formation.leader)

"""The successor of a dead leader (fault containment).

Who it is: :mod:`scenario.succession` (the first member adjacent to every other member, in the
scenario's robot order). What it does (``agent.node``): it watches the leader's liveliness token
(:func:`leader_token_key`); when the token goes (the leader's session closed or its lease
expired), it takes the leader role for a formation that now stands still (its load hangs on the
dead robot): it publishes the formation's ellipse estimated from the members' positions with
zero velocity, exchanges ellipses with the other leaders and relays them to the members, so the
other formations keep avoiding it. When the leader's token comes back, it steps down.
"""

from __future__ import annotations

from geometry.graph import can_lead, successor
from wire import keys

__all__ = ["LEADER_TOKEN", "can_lead", "leader_token_key", "successor"]

LEADER_TOKEN = "leader"  # liveliness: {prefix}/formation/{fid}/leader


def leader_token_key(prefix: str, formation: str) -> str:
    """The liveliness key the leader of ``formation`` holds while it runs."""
    return (f"{keys.validate_prefix(prefix)}/formation/"
            f"{keys.validate_id(formation, 'formation')}/{LEADER_TOKEN}")

"""The successor of a dead leader, and the standing body of a formation known dead (fault
containment).

Who the successor is: :mod:`scenario.succession` (the first member adjacent to every other
member, in the scenario's robot order). What it does (``agent.node``): it watches the leader's
liveliness token (:func:`leader_token_key`); when the token goes (the leader's session closed or
its lease expired), it takes the leader role for a formation that now stands still (its load
hangs on the dead robot): it publishes the formation's ellipse estimated from the members'
positions with zero velocity, exchanges ellipses with the other leaders and relays them to the
members, so the other formations keep avoiding it. When the leader's token comes back, it steps
down.

A formation with no successor whose every member is known dead (a fleet robot, a formation of one:
its agent holds the token of the formation named by it for as long as it runs, in a team or not)
is a body standing near its last ellipse, or near the camera's newer pose of the robot (a robot
that died in a team, whose formation of one nobody heard since the team formed): a robot whose
agent is gone gets no command, and its base stops (the world's, or a real base's, command
watchdog). The other leaders keep that ellipse
grown by :func:`standing_grow` for the rest of the run instead of stopping once ``ellipse_hold``
runs out. Only the token's going says so (positive knowledge); a formation merely silent stays
stale, held inflated, then stopped for.
"""

from __future__ import annotations

from geometry.graph import can_lead, successor
from wire import keys

__all__ = ["LEADER_TOKEN", "can_lead", "leader_token_key", "standing_grow", "stopping_distance",
           "successor", "token_formation"]

LEADER_TOKEN = "leader"  # liveliness: {prefix}/formation/{fid}/leader


def leader_token_key(prefix: str, formation: str) -> str:
    """The liveliness key the leader of ``formation`` holds while it runs."""
    return (f"{keys.validate_prefix(prefix)}/formation/"
            f"{keys.validate_id(formation, 'formation')}/{LEADER_TOKEN}")


def token_formation(prefix: str, key: str) -> str | None:
    """The formation whose leader token ``key`` is (:func:`leader_token_key`), or None."""
    head, tail = f"{prefix}/formation/", f"/{LEADER_TOKEN}"
    if not (key.startswith(head) and key.endswith(tail)):
        return None
    fid = key[len(head):-len(tail)]
    return fid if fid and "/" not in fid else None


def stopping_distance(speed: float, max_accel: float | None, dt: float) -> float:
    """How far [m] a robot moving at ``speed`` goes once its base is told to stop: nothing for a
    base that takes velocities (it stops at once); a double integrator braking at ``max_accel``
    covers at most ``speed**2 / (2 max_accel)`` plus one period at ``speed`` (the braking is
    applied per period, :func:`agent.double_integrator.brake`)."""
    if max_accel is None:
        return 0.0
    return speed * speed / (2.0 * max_accel) + speed * dt


def standing_grow(speed: float, known_age: float, lag: float, stop: float) -> float:
    """How far [m] (both semi-axes) a formation known dead can stand from its last ellipse (or
    the last pose of it): ``speed`` (top speed) over that message's age when the death was
    known (``known_age``: it may have moved on with messages not received), over ``lag`` more
    (until its base stops: one period of its last command in lock-step, the command watchdog
    in real time), plus its stopping distance ``stop`` (:func:`stopping_distance`). Fixed from
    then on: it moves no more."""
    return speed * (max(0.0, known_age) + lag) + stop

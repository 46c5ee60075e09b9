"""The assembly of one robot's control-step inputs from what it knows this tick: pure, shared by
the agent (:mod:`agent.node`, from received messages) and the in-process simulator
(:mod:`simulator.inprocess`, from the fleet's state).

No clock, no network: numbers in, the :class:`agent.control.StepInput` of
:meth:`agent.control.Controller.step` out (the caller adds the pose, goal, obstacles, shapes, last
command and footprint), with the formation's jam-rule memory (:class:`agent.control.Stall`)
carried from tick to tick.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from geometry.ellipse import Ellipse, within_reach
from leader.role import VIEW_RANGE, msg_to_ellipse
from wire.payloads import Others

from . import unicycle
from .barriers import Neighbour, Partner
from .control import FormationView, Stall, StepInput, update_stall

Kinematic = tuple[float, float, float, float]  # control point x, y [m], velocity vx, vy [m/s]
Heading = tuple[float, float, float, float, float]  # a Kinematic and the heading theta [rad]


def step_inputs(
    neighbours: Iterable[tuple[float, ...]],
    own: Ellipse | None,
    formation: str,
    formation_goal: tuple[float, float],
    others: Sequence[tuple[str, Ellipse]],
    stall: Stall,
    period: float,
    foreign: Iterable[Heading] | None = None,
    members: Iterable[Heading] = (),
    *,
    leg: tuple[float | None, bool] = (None, True),
    **rest: Any,
) -> StepInput:
    """Inputs of one robot's step (its ``stall`` the jam rule's memory after this tick).

    ``neighbours`` are (x, y, vx, vy, Df) of its graph neighbours; ``own`` is its formation's
    ellipse (None: no view, the stall memory is kept as it is); ``others`` are the other
    formations' (name, ellipse) in the order the view names them (those beyond
    :data:`leader.role.VIEW_RANGE` of ``own`` are left out, as the leader leaves them out);
    ``period`` [s] advances the jam rule; ``foreign`` (all-to-all baseline only) are the robots
    of other formations, which then replace the ellipses as pairwise rows; ``members`` are the
    other members of its formation (graph neighbours or not). Each member, and in all-to-all
    each foreign robot, is a partner of a hard separation row; the other formations' ellipses
    stay hazards for the formation's motion (its QP, tie-break) in both topologies. A neighbour
    may carry its heading as a sixth number (from its ``state``): a unicycle formation's band on
    the look-ahead points narrows by it. ``leg``: the current waypoint's heading and whether
    the member settles there, as :func:`waypoint_view` puts them in the view; ``rest``: the
    StepInput's other fields (the pose, goal, obstacles, ...), so the input is made once. The
    formations parked at their goals join the view after (:func:`with_parked`).
    """
    nb = [Neighbour(*n) for n in neighbours]
    view = None
    if own is not None:  # the formations in view (the leader's ``others`` holds no more)
        others = [(name, e) for name, e in others
                  if within_reach(own, e.cx, e.cy, e.a, VIEW_RANGE)]
        gx, gy = formation_goal
        heading, arriving = leg
        stall = update_stall(stall, FormationView(own, gx, gy), period)
        view = FormationView(own, gx, gy, formation, tuple([name for name, _e in others]),
                             stall.yielding, heading, arriving)
    hazards = [e for _name, e in others]
    partners = [Partner(*m) for m in members]
    if foreign is not None:
        foreign = list(foreign)
        ellipses: list[Ellipse] = []
        pair = [Neighbour(x, y, vx, vy, 0.0) for x, y, vx, vy, _th in foreign]
        partners += [Partner(*f) for f in foreign]
    else:
        ellipses = hazards
        pair = []
    return StepInput(neighbours=nb, others=ellipses, view=view, pairwise=pair, partners=partners,
                     hazards=hazards, stall=stall, **rest)


def predict_state(x: float, y: float, ux: float, uy: float, theta: float, age: float,
                  lookahead: float) -> tuple[float, float, float]:
    """A neighbour's ``state`` (control point (x, y), certified velocity u, heading) carried
    ``age`` seconds forward under the command it certified, as the robot executes it: (x, y,
    theta) then. A single integrator (lookahead 0) moves by u age; a unicycle drives the
    (v, omega) of eq. 6.2 for u on the exact arc of eq. 6.1, its look-ahead point following.

    Real time only: a state is the neighbour's tick for ITS pose stamp, which is older than the
    pose this robot ticks on (up to a period, plus transport). Mixing the two times puts the
    pair's barrier values apart by up to |u| age on each side, so the two halves of a
    separation row (:func:`agent.barriers.separation_row`) no longer add up to the pair
    condition and the pair dips below the boundary it sits on. Carried to this robot's pose
    stamp, both robots evaluate the pair at one time, as in lock-step (where every age is 0 and
    this returns the state unchanged)."""
    if age <= 0.0:
        return x, y, theta
    if lookahead <= 0.0:
        return x + ux * age, y + uy * age, theta
    v, omega = unicycle.to_unicycle(ux, uy, theta, lookahead)
    bx, by = unicycle.control_point(x, y, theta, -lookahead)  # the body, l behind the point
    bx, by, th = unicycle.integrate(bx, by, theta, v, omega, age)
    return (*unicycle.control_point(bx, by, th, lookahead), th)


def carry_pose(x: float, y: float, theta: float, ux: float, uy: float, age: float,
               lookahead: float) -> tuple[float, float, float]:
    """A robot's own measured BODY pose carried ``age`` seconds forward under its last
    certified command u (p + u age for a single integrator; a unicycle on the arc of
    :func:`predict_state`, its look-ahead point moving at u): (x, y, theta) then. The agent
    carries its pose by the pose's measured age, at most its declared latency
    (:func:`agent.margins.carried_age`)."""
    if age <= 0.0:
        return x, y, theta
    px, py = unicycle.control_point(x, y, theta, lookahead)
    qx, qy, th = predict_state(px, py, ux, uy, theta, age, lookahead)
    bx, by = unicycle.control_point(qx, qy, th, -lookahead)
    return bx, by, th


def with_waypoint(inputs: StepInput, heading: float | None, arriving: bool = True) -> StepInput:
    """``inputs`` with the current waypoint's heading (None: none) in the view, and whether the
    member settles on its target there (:attr:`leader.navigation.Follower.arriving`)."""
    if inputs.view is None or (heading is None and arriving):
        return inputs
    return inputs._replace(view=waypoint_view(inputs.view, heading, arriving))


def waypoint_view(view: FormationView | None, heading: float | None,
                  arriving: bool = True) -> FormationView | None:
    """The view of :func:`with_waypoint`, for a caller that replaces more fields at once."""
    if view is None or (heading is None and arriving):
        return view
    return view._replace(goal_heading=heading, arriving=arriving)


NOT_PARKED: frozenset[str] = frozenset()


def parked_of(msg: Others) -> frozenset[str]:
    """The other formations of an ``others`` message parked at their goals (their ellipses'
    ``parked``, :func:`leader.navigation.at_goal`), for :func:`step_inputs`."""
    if not any(e.parked for e in msg.ellipses):
        return NOT_PARKED
    return frozenset(e.formation for e in msg.ellipses if e.parked)


def with_parked(inputs: StepInput, parked: frozenset[str]) -> StepInput:
    """``inputs`` with the other formations parked at their goals in the view (:func:`parked_of`;
    no yield backs away from them: :func:`agent.control.yield_command`)."""
    if not parked or inputs.view is None:
        return inputs
    return inputs._replace(view=inputs.view._replace(parked=parked))


OthersView = tuple[Ellipse | None, tuple[tuple[str, Ellipse], ...]]
_VIEWS: dict[int, tuple[Others, OthersView]] = {}  # id of an ``others`` message -> its view
_VIEWS_MAX = 256  # messages remembered (emptied when full)


def others_view(msg: Others) -> OthersView:
    """An ``others`` message in the controller's form: its own ellipse (None: none yet) and the
    other formations' (name, ellipse), in its order. Remembered for the newest messages of the
    process: the members of a formation in one agent host hold the same decoded message
    (:class:`agent.inbox.DecodeMemo`), which is converted once; messages are frozen, so the
    view of one is the view of it for every reader."""
    hit = _VIEWS.get(id(msg))
    if hit is not None and hit[0] is msg:
        return hit[1]
    view = (None if msg.own is None else msg_to_ellipse(msg.own),
            tuple((m.formation, msg_to_ellipse(m)) for m in msg.ellipses))
    if len(_VIEWS) >= _VIEWS_MAX:
        _VIEWS.clear()
    _VIEWS[id(msg)] = (msg, view)
    return view

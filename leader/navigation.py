"""Goals, routes and status of one formation: the leader's :class:`Navigator` and every member's
:class:`Follower` (the keys ``goal``, ``plan``, ``status`` of docs/keys.md).

* The fleet manager sends the leader a :class:`wire.navigation.GoalMsg` (goal centroid, optional
  heading, optional waypoints). The leader's :meth:`Navigator.accept` checks it (finite, not
  inside a wall's or shelf's safe distance, newer than the goal it follows), turns the
  formation's goal shape by the heading (the shape as written in the scenario's goals is
  heading 0; no heading keeps the current one), gives each member its goal (goal centroid plus
  its turned offset), and routes the centroid: the given waypoints, else
  :func:`geometry.route.plan_route` around the walls and shelves from where the formation is
  now (unless planning is off). The result is a :class:`wire.navigation.PlanMsg`.
* Every member (the leader too) runs a :class:`Follower`: it adopts a plan from its own leader
  whose goal is newer than the one it follows, and each tick walks the route with the
  formation's ellipse centre (:func:`geometry.route.advance`); its target for the nominal command
  (eq. 4.2) is the current waypoint plus its offset (turned to the waypoint's heading where it
  has one), its own goal on the last leg.
* :meth:`Navigator.status` reports the state (``moving``, ``reached``: the centroid within the
  goal tolerance of the goal centroid on the last leg, ``stalled``: the stall clock sees the
  formation still away from its target, or its replanner finds it boxed in
  (:attr:`leader.routing.Replanner.boxed_in`), ``stopped``: the leader commanded zero for missing
  inputs, or shuts down,
  ``unreachable``: no route reaches the goal, with the reason), the distance to go along the
  route, the current waypoint, and how many goals were refused and why the last one was.

Pure: no clock, no network; the agent node and the in-process simulator call it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from geometry.ellipse import wrap_angle
from geometry.route import Point, advance, formation_radius, member_target, plan_route, route_length
from geometry.shapes import Shape, shape_distance
from wire.navigation import MAX_REASON, MAX_REFUSED, GoalMsg, PlanMsg, StatusMsg

SAME_GOAL = "the goal followed already"  # accept(): nothing changes, not counted as refused


HEADING_TOLERANCE = 0.15  # [rad] a waypoint with a heading is passed once the formation is this near it
# [m/s] a turn has settled once its outermost member moves slower than this: the reversal
# counter's floor (simulator.motion.REVERSAL_SPEED), below which a command turned round is not
# a reversal
SETTLED_SPEED = 0.05
ASIDE = math.radians(60.0)  # a centroid moving further than this off the next leg has not settled


def heading_tolerance(kp: float, rho: float | None) -> float:
    """[rad] How near a waypoint's heading the formation must have turned to pass it: at most
    HEADING_TOLERANCE, and no more than leaves its outermost member (``rho`` [m] from the
    centre; None: no rigid body, HEADING_TOLERANCE) pivoting at SETTLED_SPEED under the turn's
    pull, kp rho |error| (eq. 4.2's gain on the heading: agent.body.goal_twist). Passed sooner,
    the next leg set off while a member still swung the other way: route-head-on-aisle's pair
    turned 47 degrees in place and its rear member's command went from 0.09 m/s west to
    0.18 m/s south-east in one tick."""
    if rho is None or kp <= 0.0 or rho <= 0.0:
        return HEADING_TOLERANCE
    return min(HEADING_TOLERANCE, SETTLED_SPEED / (kp * rho))


class Follower:
    """One member's walk along its formation's route (see the module docstring). A route point
    may carry a heading (``headings``, one per point or none: the footprint planner's, or a
    hand-given ``[x, y, heading]``): the formation passes it once also turned within
    ``tolerance`` of it (:func:`heading_tolerance` of the formation's turn), when its heading is
    given to :meth:`step`."""

    __slots__ = ("robot_id", "goal", "formation_goal", "route", "index", "goal_stamp", "_offset",
                 "headings", "plan_stamp", "holding", "tolerance", "goal_heading")

    def __init__(self, robot_id: str, goal: Point, formation_goal: Point,
                 route: Sequence[Point] = (), headings: Sequence[float | None] = (),
                 tolerance: float = HEADING_TOLERANCE) -> None:
        self.robot_id = robot_id
        self.tolerance = tolerance  # [rad] a waypoint's heading counts reached this near
        self.goal_stamp = -math.inf  # the scenario's goal: any plan from the leader is newer
        self.plan_stamp = -math.inf  # the stamp of the plan followed (a replan of one goal is newer)
        # [rad] the goal shape's turn at the goal (PlanMsg.heading; the scenario's goals: 0): the
        # offsets' own, from which a waypoint's heading turns them (:meth:`step`)
        self.goal_heading = 0.0
        self._set(goal, formation_goal, route, headings)

    def _set(self, goal: Point, formation_goal: Point, route: Sequence[Point],
             headings: Sequence[float | None] = ()) -> None:
        self.goal = (goal[0], goal[1])
        self.formation_goal = (formation_goal[0], formation_goal[1])
        self.route = tuple(route) if route else (self.formation_goal,)
        self.headings: tuple[float | None, ...] = (tuple(headings) if len(headings) == len(self.route)
                                                   else ())
        self.index = 0
        self.holding = False
        self._offset = (goal[0] - formation_goal[0], goal[1] - formation_goal[1])

    @property
    def heading(self) -> float | None:
        """The current waypoint's heading (the goal shape's turn, as GoalMsg.heading), or None."""
        return self.headings[self.index] if self.headings else None

    @property
    def arriving(self) -> bool:
        """On the last leg (its target is its own goal), or holding (its slot where the formation
        holds): where a member settles on its target (:func:`agent.body.member_nominal`), not on
        a waypoint the formation passes."""
        return self.holding or self.index >= len(self.route) - 1

    def follow(self, route: Sequence[Point], headings: Sequence[float | None] = ()) -> None:
        """A new route to the same goal (a replan), from its first point."""
        self._set(self.goal, self.formation_goal, route, headings)

    def take(self, route: Sequence[Point], headings: Sequence[float | None], cx: float, cy: float,
             heading: float | None) -> None:
        """A replan's route (:class:`leader.routing.Update`), or where it has none, hold at
        (cx, cy) turned to ``heading``: what the leader and, through ``plan``, every member
        does with a new route."""
        if route:
            self.follow(route, headings)
        else:
            self.hold(cx, cy, heading)

    def hold(self, cx: float, cy: float, heading: float | None) -> None:
        """Stay parked where the formation is (no route reaches the goal); holding already:
        stay where it holds."""
        if self.holding:
            return
        self._set(self.goal, self.formation_goal, ((cx, cy), self.formation_goal),
                  (heading, None) if heading is not None else ())
        self.holding = True

    def adopt(self, plan: PlanMsg) -> bool:
        """Follow ``plan`` if it is newer than the goal followed now and names this member, or
        is a newer route to that goal (a replan: same goal stamp, a stamp no older, another
        route: a leader that takes a goal and plans its footprint's route in one tick puts both)."""
        replan = (plan.goal_stamp == self.goal_stamp and plan.stamp >= self.plan_stamp
                  and (plan.route, plan.headings) != (self.route, self.headings))
        if not (plan.goal_stamp > self.goal_stamp or replan):
            return False
        goal = plan.goal_of(self.robot_id)
        if goal is None:
            return False
        self.goal_stamp = plan.goal_stamp
        self.plan_stamp = plan.stamp
        self.goal_heading = plan.heading if plan.heading is not None else 0.0
        self._set(goal, (plan.cx, plan.cy), plan.route, plan.headings)
        return True

    def step(self, cx: float, cy: float, heading: float | None = None,
             motion: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[Point, Point]:
        """(this member's target, the formation's current waypoint) for the ellipse centre
        (cx, cy) of this tick; ``heading``: the formation's (as the route's headings), if known;
        ``motion``: its centroid's velocity [m/s] and its outermost member's speed of rotation
        [m/s] (the ellipse's rates). A waypoint with a heading is passed once the formation has
        turned within ``tolerance`` of it and, while its centroid drifts more than ASIDE off
        the leg after it, once no member can move at SETTLED_SPEED: route-give-way's hexagon
        (single integrators) turned within the tolerance while its centroid still crept
        0.035 m/s north and pivoted at 0.035 m/s; the leg after it led east, and its outer
        member's command went from 0.056 m/s north-west to 0.077 m/s south-east in one tick."""
        if not self.holding:
            while True:
                k = advance(self.route, self.index, cx, cy)
                want = self.heading
                if k == self.index or (heading is not None and want is not None and (
                        abs(wrap_angle(heading - want)) > self.tolerance
                        or self._unsettled(cx, cy, motion) or self._turns_back(heading, motion))):
                    break
                self.index += 1
        want = self.heading
        turned = 0.0 if want is None else want - self.goal_heading
        return (member_target(self.route, self.index, self.goal, self._offset, turned),
                self.route[self.index])

    def _unsettled(self, cx: float, cy: float, motion: tuple[float, float, float]) -> bool:
        """Whether a member may still move at SETTLED_SPEED or more while the centroid drifts
        more than ASIDE from the leg after the current waypoint (that leg then turns some
        member's command round in one tick)."""
        if settled(motion) or self.index + 1 >= len(self.route):
            return False
        vx, vy, _spin = motion
        speed = math.hypot(vx, vy)
        nx, ny = self.route[self.index + 1][0] - cx, self.route[self.index + 1][1] - cy
        leg = math.hypot(nx, ny)
        return leg > 1e-9 and nx * vx + ny * vy < math.cos(ASIDE) * leg * speed

    def _turns_back(self, heading: float, motion: tuple[float, float, float]) -> bool:
        """Whether the next waypoint's heading lies the other way round from ``heading`` than
        the current one's, while a member may still move at SETTLED_SPEED or more: passing on,
        the formation's turn would reverse in one tick and its outer member's command with it.
        route-head-on-aisle's pair, let go after waiting and turning at 0.067 m/s towards -1.178
        rad, passed it at -1.104 (within the tolerance) for -0.785 beyond it: a reversal."""
        if settled(motion) or self.index + 1 >= len(self.headings):
            return False
        nxt, want = self.headings[self.index + 1], self.headings[self.index]
        if nxt is None or want is None:
            return False
        return wrap_angle(want - heading) * wrap_angle(nxt - heading) < 0.0


def at_goal(follower: Follower, centroid: Point, tolerance: float) -> bool:
    """Whether the formation whose leader walks ``follower`` stands at its goal: on the last leg
    of its route, its ``centroid`` within ``tolerance`` [m] of the goal centroid (the status
    ``reached``). Such a formation holds there until a new goal: its leader says so on its
    ellipse (``parked``), and no formation yields to it (:func:`agent.control.yield_command`)."""
    return (follower.index >= len(follower.route) - 1
            and math.dist(centroid, follower.formation_goal) <= tolerance)


def settled(motion: tuple[float, float, float]) -> bool:
    """Whether no member can move at SETTLED_SPEED or more (``motion``: the centroid's velocity
    and the outermost member's speed of rotation [m/s], as :meth:`Follower.step` takes it)."""
    return math.hypot(motion[0], motion[1]) + motion[2] <= SETTLED_SPEED


def turn(offsets: Mapping[str, Point], heading: float) -> dict[str, Point]:
    """The offsets turned by ``heading`` [rad] about the centroid."""
    c, s = math.cos(heading), math.sin(heading)
    return {m: (c * x - s * y, s * x + c * y) for m, (x, y) in offsets.items()}


class Navigator:
    """The leader's part (see the module docstring). ``reference`` holds each member's goal
    offset from the goal centroid as written in the scenario (heading 0)."""

    def __init__(self, formation: str, leader_id: str, reference: Mapping[str, Point],
                 goal: Point, route: Sequence[Point] = (), planner: bool = True,
                 tolerance: float = 0.05, heading: float | None = None,
                 fleet: Sequence[str] = ()) -> None:
        self.formation = formation
        # every formation of the scenario, this one included (on ``status``, version 2)
        self.fleet = tuple(sorted({formation, *fleet})) if fleet else ()
        self.leader_id = leader_id
        self.reference = dict(reference)
        self.radius = formation_radius(list(self.reference.values()))
        self.planner = planner
        self.tolerance = tolerance
        self.goal_stamp = -math.inf
        self.goal = (goal[0], goal[1])
        self.heading = heading
        self.offsets = turn(self.reference, heading) if heading is not None else dict(self.reference)
        self.route = tuple(route) if route else (self.goal,)
        self.headings: tuple[float | None, ...] = ()  # one per route point, or none
        self.replans = 0  # routes to the goal followed planned again (leader.routing)
        self.rejected = 0  # goals refused (inside an obstacle, stale, another formation's)
        self.refusal = ""  # why the last goal was refused (on ``status``, version 2)
        self._refused_msg: GoalMsg | None = None  # the last goal refused (one put again counts once)
        self.unreachable = ""  # why no route reaches the goal ("" while one does): the state

    def same(self, msg: GoalMsg) -> bool:
        """Whether ``msg`` asks for the goal followed now (a fleet manager may send it again)."""
        return (math.isfinite(self.goal_stamp) and msg.formation == self.formation
                and (msg.x, msg.y) == self.goal
                and (msg.heading is None or msg.heading == self.heading)
                and (not msg.waypoints or tuple(msg.waypoints) + (self.goal,) == self.route))

    def problem(self, msg: GoalMsg, shapes: Sequence[Shape]) -> str | None:
        """Why the leader refuses ``msg``, or None."""
        if msg.formation != self.formation:
            return f"goal for formation {msg.formation!r}, not {self.formation!r}"
        if not msg.stamp > self.goal_stamp:
            return f"goal stamped {msg.stamp} is not newer than the one followed ({self.goal_stamp})"
        offsets = turn(self.reference, msg.heading) if msg.heading is not None else self.offsets
        for sh in shapes:
            for m, (ox, oy) in offsets.items():
                if shape_distance(msg.x + ox, msg.y + oy, sh)[0] < sh.ds:
                    return f"the goal of {m!r} lies within the safe distance of {sh.kind} {sh.name!r}"
            for k, (wx, wy) in enumerate(msg.waypoints):
                if shape_distance(wx, wy, sh)[0] < sh.ds:
                    return f"waypoint {k} lies within the safe distance of {sh.kind} {sh.name!r}"
        return None

    def accept(self, msg: GoalMsg, stamp: float, centroid: Point, shapes: Sequence[Shape]) -> str | None:
        """Take ``msg`` as the formation's goal, stamped ``stamp`` (its own stamp in real time,
        the tick's simulated time in lock-step); the route starts at ``centroid``. Returns why it
        was refused, or None when it was taken (then :meth:`plan` is the new plan). The same
        message refused and put again (``formation goal`` puts it every second until the status
        shows it) is refused again but counted once: a busy leader's status could otherwise show
        one goal refused twice."""
        if self.same(msg):
            return SAME_GOAL
        why = self.problem(msg, shapes)
        if why is None and not stamp > self.goal_stamp:
            why = f"goal stamped {stamp} is not newer than the one followed"
        if why is not None:
            self.refuse(why, msg)
            return why
        self.goal_stamp = stamp
        self.goal = (msg.x, msg.y)
        if msg.heading is not None:
            self.heading = msg.heading
            self.offsets = turn(self.reference, msg.heading)
        self.headings = ()
        if msg.waypoints:
            self.route = tuple(msg.waypoints) + (self.goal,)
            if msg.headings:
                self.headings = msg.headings + (msg.heading,)
        elif self.planner and shapes:
            self.route = plan_route(centroid, self.goal, shapes, self.radius)
        else:
            self.route = (self.goal,)
        return None

    def refuse(self, why: str, msg: GoalMsg | None = None) -> None:
        """Count a refused goal and keep why (the door's refusals come here too); ``msg``, the
        goal refused, is counted once when it is put again (the same refusal)."""
        self.refusal = why[:MAX_REASON]
        if msg is not None and msg == self._refused_msg:
            return
        self.rejected += 1
        self._refused_msg = msg

    def plan(self, stamp: float) -> PlanMsg:
        gx, gy = self.goal
        members = tuple((m, gx + ox, gy + oy) for m, (ox, oy) in self.offsets.items())
        return PlanMsg(self.formation, self.goal_stamp if math.isfinite(self.goal_stamp) else 0.0,
                       gx, gy, self.heading, self.route, members, stamp, self.headings)

    def hold_plan(self, stamp: float, cx: float, cy: float, heading: float | None) -> PlanMsg:
        """No route: the plan that parks the members where the formation is (the goal shape
        turned by ``heading``, centred at (cx, cy)); the leader keeps the goal and says why on
        ``status``."""
        offsets = turn(self.reference, heading) if heading is not None else self.offsets
        members = tuple((m, cx + ox, cy + oy) for m, (ox, oy) in offsets.items())
        return PlanMsg(self.formation, self.goal_stamp if math.isfinite(self.goal_stamp) else 0.0,
                       cx, cy, heading, ((cx, cy),), members, stamp,
                       (heading,) if heading is not None else ())

    def status(self, follower: Follower, centroid: Point, stalled: bool, stopped: bool,
               stamp: float, refused: int = 0) -> StatusMsg:
        """The status from the leader's own follower (the route as the formation walks it);
        ``refused`` counts goals refused before they reached the Navigator (at the door)."""
        route, index = follower.route, follower.index
        gx, gy = follower.formation_goal
        state = ("stopped" if stopped else "reached" if at_goal(follower, centroid, self.tolerance)
                 else "unreachable" if self.unreachable else "stalled" if stalled else "moving")
        wx, wy = route[index]
        return StatusMsg(self.formation, state, self.leader_id,
                         follower.goal_stamp if math.isfinite(follower.goal_stamp) else 0.0,
                         gx, gy, self.heading, route_length(centroid, route[index:]), index,
                         len(route), wx, wy, stamp,
                         reason=self.unreachable[:MAX_REASON] if state == "unreachable" else "",
                         refused=min(self.rejected + refused, MAX_REFUSED), refusal=self.refusal,
                         fleet=self.fleet)

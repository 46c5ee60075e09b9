"""The in-process simulator's leaders' route planning: each ``method: rigid`` formation without
hand-given waypoints keeps a :class:`leader.route_driver.RouteDriver` (the agent's leader drives
the same one); every tick its leader's view (its ellipse, the circles, the other formations'
ellipses) decides whether to plan again, and the new route reaches the leader at once and the
other members a tick later (as the agents' ``plan`` message does in lock-step)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from agent.barriers import Obstacle
from agent.body import Footprint, pose_of
from geometry.ellipse import Ellipse, within_reach, wrap_angle
from geometry.shapes import Shape
from leader.navigation import Follower
from leader.route_driver import RouteDriver
from leader.routing import REACHED, STALLED, UNREACHABLE, Other, Reason, Replanner, Thing, Update
from scenario import Scenario
from scenario.routes import RIGID, StartPlan, footprint_body


class Replans:
    """Per formation: its :class:`RouteDriver` (its :class:`Replanner` and its view of still
    things)."""

    def __init__(self, scenario: Scenario, starts: dict[str, StartPlan],
                 footprints: Sequence[Footprint], members: dict[str, tuple[int, ...]],
                 views: Mapping[str, tuple[Shape, ...]] | None = None) -> None:
        """``views``: the walls and shelves a formation (by name) plans round instead of the
        scenario's."""
        views = views or {}
        self.scenario = scenario
        self.members = members
        self.footprints = footprints
        self.drivers: dict[str, RouteDriver] = {}
        self.updates: list[tuple[float, str, Reason, int]] = []  # (t, formation, why, waypoints)
        # per formation of a lifelong run's gathering robot: the formations of one its leader
        # does not see (its allies, kept apart by separation rows) and those it plans round as
        # formations where a way does, else as robots (its mates: agent.errand.mates_at,
        # leader.routing.round_mates)
        self.unseen: Mapping[str, frozenset[str]] = {}
        self.mates: Mapping[str, frozenset[str]] = {}
        # [m] how far beyond its own ellipse a leader sees the other formations: a lifelong run
        # takes the agents' (leader.role.VIEW_RANGE, as a leader's ``others`` holds them);
        # fixed formations plan round every formation
        self.reach = math.inf

        # a new route reaches the leader's own follower at once and the other members a tick
        # later, as the agents' ``plan`` message does in lock-step: (formation, update, heading)
        self._pending: list[tuple[str, Update, Ellipse]] = []
        ids = [r.id for f in scenario.formations for r in f.robots]
        self.leader = {f.name: ids.index(f.leader) for f in scenario.formations}
        ctl = scenario.controller
        self.rigid = ctl.method == RIGID
        if not self.rigid or ctl.planner == "none":
            return
        for f in scenario.formations:
            if f.waypoints:
                continue
            body, start, turn = footprint_body(scenario, f)
            gx, gy = f.goal_centroid
            r = Replanner(body, turn, (gx, gy, turn), views.get(f.name, scenario.shapes), start,
                          speed=scenario.robot.max_speed)
            r.name = f.name
            r.unreachable = starts[f.name].reason
            r.last_plan = 0.0
            # the first tick plans with what the leader sees then (a moving thing's lane, the
            # other formations), as the agent's leader does (agent.replan.LeaderRoutes)
            r.due = Reason.START
            fp = footprints[members[f.name][0]]
            self.drivers[f.name] = RouteDriver(r, fp.goal_turn, scenario.robot.radius)

    @property
    def planners(self) -> dict[str, Replanner]:
        """Per planned formation: the policy of its route."""
        return {name: d.replanner for name, d in self.drivers.items()}

    def heading(self, name: str, own: Ellipse) -> float | None:
        """The formation's heading (the goal shape's turn) from its ellipse, under method rigid
        (hand-given waypoints may carry headings too)."""
        if not self.rigid:
            return None
        fp = self.footprints[self.members[name][0]]
        return wrap_angle(pose_of(own, fp.alpha0).theta - fp.goal_turn)

    def tick(self, t: float, ellipses: dict[str, Ellipse], obstacles: Sequence[Obstacle],
             followers: Sequence[Follower]) -> None:
        """Plan again where a leader would, and hand the route to the members."""
        for name, upd, at in self._pending:
            self._hand(upd, name, at, followers, leader=False)
        self._pending = []
        planners = self.planners
        waiting = any(p.unreachable or p.giving_way for p in planners.values())
        others = self._reports(ellipses) if waiting else {}  # read only by those (give_way)
        for name, driver in self.drivers.items():
            own = ellipses[name]
            fp = self.footprints[self.members[name][0]]
            pose = pose_of(own, fp.alpha0)
            seen = self._things(name, driver, ellipses, obstacles)
            driver.replanner.mates = self.mates.get(name, frozenset())
            if t == 0.0 and driver.replanner.unreachable:  # no route at the start: hold from
                hold = Update((), (), Reason.START, driver.replanner.unreachable)  # the first tick
                self._hand(hold, name, own, followers)
                self._hand(hold, name, own, followers, leader=False)
            lead = followers[self.leader[name]]
            new = driver.tick(t, (pose.cx, pose.cy, pose.theta), lead, seen, others)
            if new is None:  # no plan, or no way round the formations in the way: keep the route
                continue
            self.updates.append((t, name, new.why, len(new.route)))
            self._hand(new, name, own, followers)
            self._pending.append((name, new, own))

    def _reports(self, ellipses: dict[str, Ellipse]) -> dict[str, Other]:
        """What each planned formation's leader would report on ``status`` (its state and
        goal; reached within the goal tolerance of its goal centroid; stalled where it is boxed
        in, as the agent's leader also says when its stall clock runs), where it is now."""
        out = {}
        tol = self.scenario.goal_tolerance + self.scenario.robot.control_offset
        for name, p in self.planners.items():
            e = ellipses[name]
            gx, gy = p.goal[0], p.goal[1]
            # one standing aside follows a route (the agent's leader reports it moving)
            state = (REACHED if math.dist((e.cx, e.cy), (gx, gy)) <= tol else
                     UNREACHABLE if p.unreachable and not p.giving_way else
                     STALLED if p.boxed_in else "moving")
            out[name] = Other(state, e.cx, e.cy, gx, gy, e.a)
        return out

    def _hand(self, upd: Update, name: str, own: Ellipse, followers: Sequence[Follower],
              leader: bool = True) -> None:
        """``upd`` (planned with the formation at ``own``) to the leader's follower (``leader``)
        or to every other member's."""
        heading = self.heading(name, own)
        for i in self.members[name]:
            if (i == self.leader[name]) != leader:
                continue
            followers[i].take(upd.route, upd.headings, own.cx, own.cy, heading)

    def _things(self, name: str, driver: RouteDriver, ellipses: dict[str, Ellipse],
                obstacles: Sequence[Obstacle]) -> list[Thing]:
        """What the leader of ``name`` sees, as the agent's leader has it
        (:meth:`agent.replan.LeaderRoutes.tick`): the circles (static where still at the
        driver's first look) and the other formations' ellipses in its view (within
        :attr:`reach` of its own, but its allies)."""
        specs = self.scenario.obstacles
        static = driver.look((s.name, o.vx, o.vy) for o, s in zip(obstacles, specs, strict=True))
        out = [Thing(f"obstacle/{spec.name}", o.x, o.y, math.hypot(o.vx, o.vy), o.ds,
                     spec.name in static, o.vx, o.vy)
               for o, spec in zip(obstacles, specs, strict=True)]
        radius, own = self.scenario.robot.radius, ellipses[name]
        unseen = self.unseen.get(name, frozenset())
        out += [Thing(f"formation/{other}", e.cx, e.cy, math.hypot(e.vx, e.vy), e.a + radius)
                for other, e in ellipses.items() if other != name and other not in unseen
                and within_reach(own, e.cx, e.cy, e.a, self.reach)]
        return out

    def summary(self) -> dict:
        """What ``summary.json`` says of the plans (only where a formation is planned)."""
        if not self.planners:
            return {}
        return {"replans": [{"t": round(t, 3), "formation": n, "why": w.value, "waypoints": k}
                            for t, n, w, k in self.updates],
                "unreachable": {n: p.unreachable for n, p in self.planners.items() if p.unreachable}}

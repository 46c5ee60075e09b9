"""The agent's part in navigation: walls and shelves from ``obstacles``, the route walk, and, on
the leader, goals, plans and status (:mod:`leader.navigation` holds the logic; this holds the
Zenoh side).

* Every member walks its formation's route (:class:`leader.navigation.Follower`, started on the
  route in its configuration) and adopts the plans its leader publishes on
  ``{prefix}/formation/{fid}/plan`` (only that key, so only its own leader's).
* The leader takes goals from ``{prefix}/formation/{fid}/goal`` (:class:`Navigator`; stamped
  with the goal's own stamp in real time, with the tick's simulated time in lock-step), adopts
  the new plan itself, publishes it at once and then every :data:`REPUBLISH_S` (a member that
  restarts gets it), and publishes its ``status`` every :data:`STATUS_PERIOD_S` (and answers it
  as a queryable, from any thread, with the latest one).

Goals and plans are not waited for: a message that arrives is used at the next tick. Malformed
messages are dropped and counted (``dropped``); refused goals are counted (``rejected``).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import zenoh

from agent.body import motion_of, pose_of
from agent.config import AgentConfig
from agent.replan import LeaderRoutes
from geometry.ellipse import Ellipse, wrap_angle
from geometry.shapes import Shape
from leader.navigation import SAME_GOAL, Follower, Navigator, heading_tolerance
from leader.routing import Other
from scenario.extent import Extent, goal_problem
from scenario.limits import COORDINATE
from wire import keys
from wire.navigation import (
    MAX_REASON,
    GoalMsg,
    PlanMsg,
    StatusMsg,
    decode_goal,
    decode_plan,
    decode_status,
    encode_nav,
)
from wire.payloads import DecodeError, EllipseMsg, ObstacleMsg, ShapeMsg
from wire.shapes import msg_to_shape
from wire.stamps import FUTURE, check_stamp
from wire.traffic import CountingPublisher, TrafficCounter, in_order

logger = logging.getLogger(__name__)

PLAN_EPS = 1e-9  # [s] stamps within this are the same tick's
MAX_PENDING_PLANS = 8  # unhandled plans kept (the newest): a leader puts one a tick at most
STATUS_PERIOD_S = 1.0  # [s] status publication period (stamp time: simulated in lock-step)
REPUBLISH_S = 1.0  # [s] the leader puts its plan again this often
STALLED_AFTER_S = 2.0  # [s] still this long away from the goal (agent.control.update_stall): stalled
GOAL_FUTURE_S = 1.0  # [s] real time: a goal stamped further ahead of the leader's clock is refused
GOAL_MAX_AGE_S = 5.0  # [s] real time: an older goal is refused (the goal command re-sends each second)
REPORT_MAX_AGE_S = 5.0  # [s] another leader's status older than this (by its stamp) is not used


def leader_routes(cfg: AgentConfig) -> LeaderRoutes | None:
    """Method rigid with the planner on: the leader's footprint replanning (agent.replan); a
    route given by hand (the scenario's waypoints) is never planned again."""
    fp = cfg.footprint
    if fp is None or not cfg.planner:
        return None
    return LeaderRoutes(fp, cfg.radius, cfg.control.epsilon + cfg.control.offset, cfg.formation_goal,
                        None, cfg.route_by_hand, cfg.formation, cfg.control.max_speed,
                        frozenset(cfg.mates))


def config_extent(cfg: AgentConfig) -> Extent:
    """The world's extent a goal must lie in: the configuration's, else the coordinate range."""
    if cfg.extent is None:
        return Extent(COORDINATE.lo, COORDINATE.lo, COORDINATE.hi, COORDINATE.hi)
    return Extent(*cfg.extent)


def stamp_problem(goal_stamp: float, now: float) -> str | None:
    """Real time: why a goal's stamp is refused against the leader's clock ``now``, or None:
    the one stamp check of every input (:func:`wire.stamps.check_stamp`: too far in the future,
    then too old), with the goal's window; "older than the goal followed" is the Navigator's."""
    why = check_stamp(now, goal_stamp, None, GOAL_FUTURE_S, GOAL_MAX_AGE_S)
    if why == FUTURE:
        return f"goal stamped {goal_stamp - now:.3f} s in the future"
    if why is not None:
        return f"goal stamped {now - goal_stamp:.3f} s ago (more than {GOAL_MAX_AGE_S} s)"
    return None


class NavKeys(NamedTuple):
    """The formation's navigation keys."""

    plan: str
    goal: str
    status: str


@dataclass
class NavCounts:
    """What the navigation part counts (``nav`` in the agent's counters)."""

    goals: int = 0  # goals taken
    plans: int = 0  # plans adopted (members)
    dropped: int = 0  # malformed goals or plans
    goals_refused: int = 0  # goals outside the world, not finite or with over-long routes


@dataclass
class Sent:
    """The leader's last status (its bytes, for queries) and when it last put a status and a plan."""

    status_bytes: bytes | None = None
    status_at: float = -math.inf
    plan_at: float = -math.inf


class StatusBook:
    """The other leaders' statuses, each formation's newest with the one before it."""

    def __init__(self) -> None:
        self._got: dict[str, tuple[StatusMsg, StatusMsg | None]] = {}

    def hear(self, status: StatusMsg) -> None:
        """Keep ``status`` if it is one of its formation's two newest by stamp (one of a stamp
        already kept replaces it: the same tick's again, a queryable's answer)."""
        newest, before = self._got.get(status.formation, (None, None))
        if newest is None or status.stamp >= newest.stamp:
            keep = before if newest is None or status.stamp == newest.stamp else newest
            self._got[status.formation] = (status, keep)
        elif before is None or status.stamp >= before.stamp:
            self._got[status.formation] = (newest, status)

    def view(self, stamp: float, seen: Sequence[EllipseMsg], lockstep: bool) -> dict[str, Other]:
        """The formations of ``seen`` as last reported (statuses at most REPORT_MAX_AGE_S old),
        where their ellipses are now. Lock-step: as reported before the tick stamped ``stamp``;
        a leader puts its status at the end of its tick, before its command, so every status of
        an earlier stamp has come, and one of this tick may or may not have."""
        out = {}
        for e in seen:
            st, before = self._got.get(e.formation, (None, None))
            if lockstep and st is not None and st.stamp >= stamp - PLAN_EPS:
                st = before
            if st is not None and abs(stamp - st.stamp) <= REPORT_MAX_AGE_S:
                out[e.formation] = Other(st.state, e.cx, e.cy, st.gx, st.gy, e.a)
        return out


class NavPart:
    """One agent's navigation state and its Zenoh endpoints (see the module docstring)."""

    def __init__(self, cfg: AgentConfig, leader: bool) -> None:
        self.cfg = cfg
        p = cfg.prefix
        fp = cfg.footprint
        # the footprint's per-tick constants (alpha0, goal turn, rho), taken once: the config
        # is frozen
        self._frame = None if fp is None else (fp.alpha0, fp.goal_turn, fp.rho)
        self.follower = Follower(cfg.robot_id, cfg.goal, cfg.formation_goal, cfg.route,
                                 cfg.route_headings, heading_tolerance(
                                     cfg.control.kp, None if cfg.footprint is None
                                     else cfg.footprint.rho))
        self.navigator: Navigator | None = None
        self.routes: LeaderRoutes | None = None  # method rigid: the footprint's replanning
        if leader:
            gx, gy = cfg.formation_goal
            ref = {m: (x - gx, y - gy) for m, x, y in cfg.member_goals} or {cfg.robot_id: (0.0, 0.0)}
            role = cfg.leader or cfg.standby
            fleet = (cfg.formation, *(role.other_formations if role is not None else ()))
            self.navigator = Navigator(cfg.formation, cfg.robot_id, ref, cfg.formation_goal,
                                       cfg.route, cfg.planner, cfg.goal_tolerance + cfg.control.offset,
                                       fleet=fleet)
            self.navigator.headings = self.follower.headings
            self.routes = leader_routes(cfg)
        self.keys = NavKeys(keys.plan_key(p, cfg.formation), keys.goal_key(p, cfg.formation),
                            keys.status_key(p, cfg.formation))
        self.shapes: tuple[Shape, ...] = ()
        self._shape_src: tuple[ShapeMsg, ...] = ()
        self._lock = threading.Lock()
        self._goal: GoalMsg | None = None  # newest unhandled goal (leader)
        self._plans: list[PlanMsg] = []  # unhandled plans, in arrival order (member)
        self._reports = StatusBook()  # the other leaders' statuses (routes)
        self._sent = Sent()
        self._counter: TrafficCounter | None = None
        self._pubs: dict[str, CountingPublisher] = {}
        self._decls: list[Any] = []
        self.extent = config_extent(cfg)
        self.counts = NavCounts()
        self.stopped = False  # the leader's last tick commanded zero for missing inputs
        self._centroid = (math.nan, math.nan)  # the formation's last known ellipse centre

    @property
    def rejected(self) -> int:
        return self.navigator.rejected if self.navigator is not None else 0

    @property
    def refusal(self) -> str:
        """Why the last refused goal was refused ("" if none was; leaders only)."""
        return self.navigator.refusal if self.navigator is not None else ""

    # --- wiring ------------------------------------------------------------------------------

    def open(self, session: zenoh.Session, counter: TrafficCounter) -> None:
        self._counter = counter
        if self.navigator is None:
            self._decls.append(session.declare_subscriber(self.keys.plan, in_order(self._on_plan)))
            return
        for k in (self.keys.plan, self.keys.status):
            self._pubs[k] = CountingPublisher(session.declare_publisher(k), counter)
        self._decls.append(session.declare_subscriber(self.keys.goal, in_order(self._on_goal)))
        self._decls.append(session.declare_queryable(self.keys.status, self._on_query))
        if self.routes is not None:  # who is waiting for whom (leader.routing: giving way)
            self._decls.append(session.declare_subscriber(
                keys.all_formations_key(self.cfg.prefix, keys.STATUS), in_order(self._on_status)))

    def close(self, stamp: float) -> None:
        """Leader: a last ``stopped`` status; then undeclare everything."""
        try:
            if self.navigator is not None and self.keys.status in self._pubs:
                self._publish_status(self.status_now(stamp, self._centroid, stopped=True))
        except Exception:  # shutting down: log, keep closing
            logger.debug("last status failed", exc_info=True)
        if self.routes is not None:
            self.routes.close()
        for d in [*self._decls, *self._pubs.values()]:
            try:
                d.undeclare()
            except Exception:
                logger.debug("undeclare failed", exc_info=True)
        self._decls.clear()
        self._pubs.clear()

    def _count(self, sample: zenoh.Sample) -> bytes:
        data = sample.payload.to_bytes()
        if self._counter is not None:
            self._counter.count_recv(str(sample.key_expr), len(data))
        return data

    def _decoded(self, sample: zenoh.Sample, decode: Callable[[bytes], Any], what: str) -> Any:
        """The sample's message, or None: malformed, dropped and counted."""
        try:
            return decode(self._count(sample))
        except DecodeError as exc:
            with self._lock:
                self.counts.dropped += 1
            logger.warning("%s: dropped a %s: %s", self.cfg.robot_id, what, exc)
            return None

    def _on_goal(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        goal = self._decoded(sample, decode_goal, "goal")
        if goal is not None:
            self.offer_goal(goal)

    def offer_goal(self, goal: GoalMsg) -> None:
        """A goal received (the newest waits for the next tick; any thread)."""
        with self._lock:
            self._goal = goal

    def _on_plan(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        plan = self._decoded(sample, decode_plan, "plan")
        if plan is not None:
            with self._lock:
                if plan.formation == self.cfg.formation:
                    self._plans = [*self._plans[1 - MAX_PENDING_PLANS:], plan]

    def _on_status(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        status = self._decoded(sample, decode_status, "status")
        if status is None or status.formation == self.cfg.formation:
            return
        with self._lock:
            self._reports.hear(status)

    def _due_plans(self, stamp: float, lockstep: bool) -> list[PlanMsg]:
        """The plans this tick adopts (under the lock). Real time: the newest. Lock-step: every
        plan stamped before this tick, in order; one stamped this tick was put while this tick
        runs and waits for the next, as the in-process simulator hands it, whether or not it has
        already arrived."""
        plans = self._plans
        if not lockstep:
            self._plans = []
            return plans[-1:]
        due = [p for p in plans if p.stamp < stamp - PLAN_EPS]
        self._plans = [p for p in plans if p.stamp >= stamp - PLAN_EPS]
        return due

    def reports(self, stamp: float, seen: Sequence[EllipseMsg], lockstep: bool = False
                ) -> dict[str, Other]:
        """The other formations in view as their leaders reported them (:class:`StatusBook`)."""
        with self._lock:
            return self._reports.view(stamp, seen, lockstep)

    def _on_query(self, query: zenoh.Query) -> None:  # Zenoh thread
        data = self._sent.status_bytes
        if data is None:
            return
        try:
            query.reply(self.keys.status, data)
        except Exception:  # the querier went away
            logger.debug("status reply failed", exc_info=True)

    # --- each tick ---------------------------------------------------------------------------

    def update_shapes(self, shapes: tuple[ShapeMsg, ...]) -> tuple[Shape, ...]:
        """The walls and shelves of this tick's ``obstacles`` (converted when they change)."""
        if shapes is not self._shape_src and shapes != self._shape_src:
            self.shapes = tuple(msg_to_shape(m) for m in shapes)
        self._shape_src = shapes
        return self.shapes

    def step(self, stamp: float, lockstep: bool, cx: float, cy: float, own: Ellipse | None = None,
             seen: tuple[Sequence[ObstacleMsg], Sequence[EllipseMsg]] = ((), ())):
        """This tick's (target, current waypoint) for the ellipse centre (cx, cy); on the
        leader, goals first (a goal taken now is planned from (cx, cy)), then under method
        rigid its replanning (``own``: the formation's ellipse; ``seen``: the circles and the
        other formations' ellipses)."""
        with self._lock:
            goal, self._goal = self._goal, None
            plans = self._due_plans(stamp, lockstep)
        nav = self.navigator
        if nav is not None and goal is not None:
            self._take_goal(nav, goal, stamp, lockstep, (cx, cy))
        for plan in plans:
            if self.follower.adopt(plan):
                self.counts.plans += 1
        self._centroid = (cx, cy)
        heading = None
        motion = (0.0, 0.0, 0.0)  # the formation's (Follower.step)
        frame = self._frame
        if frame is not None and own is not None:
            alpha0, goal_turn, rho = frame
            heading = wrap_angle(pose_of(own, alpha0).theta - goal_turn)
            motion = motion_of(own, rho)
        if nav is not None and self.routes is not None and own is not None:
            self._replan(nav, self.routes, stamp, lockstep, own, heading, seen)
        target, waypoint = self.follower.step(cx, cy, heading, motion)
        if nav is not None and (math.isfinite(nav.goal_stamp) or nav.replans) \
                and stamp - self._sent.plan_at >= REPUBLISH_S:
            self.put_plan(self.plan_now(nav, stamp), stamp)
        return target, waypoint

    def plan_now(self, nav: Navigator, stamp: float) -> PlanMsg:
        """The plan the members are to follow: the route, or where to hold."""
        if self.follower.holding:
            hx, hy = self.follower.route[0]
            return nav.hold_plan(stamp, hx, hy, self.follower.headings[0] if self.follower.headings
                                 else None)
        return nav.plan(stamp)

    def _replan(self, nav: Navigator, routes: LeaderRoutes, stamp: float, lockstep: bool,
                own: Ellipse, heading: float | None,
                seen: tuple[Sequence[ObstacleMsg], Sequence[EllipseMsg]]) -> None:
        """Leader, method rigid: take a new route (or hold) when one is ready; publish it."""
        r = routes.replanner  # the others' reports matter only to one with no route, aside,
        reports = self.reports(stamp, seen[1], lockstep) if r.unreachable or r.giving_way or r.parked(
            (own.cx, own.cy, 0.0)) or r.stuck(stamp) else {}  # parked or stuck (in one's way)
        upd = routes.tick(stamp, lockstep, own, self.follower, self.shapes, seen[0], seen[1], reports)
        if upd is None:
            return
        nav.replans += 1
        nav.unreachable = upd.reason[:MAX_REASON]
        if upd.route:
            nav.route, nav.headings = upd.route, upd.headings
        self.follower.take(upd.route, upd.headings, own.cx, own.cy, heading)
        logger.info("%s: formation %s plans again (%s): %s", self.cfg.robot_id, self.cfg.formation,
                    upd.why, f"route of {len(upd.route)}" if upd.route else upd.reason)
        self.put_plan(self.plan_now(nav, stamp), stamp)

    def _take_goal(self, nav: Navigator, goal: GoalMsg, stamp: float, lockstep: bool,
                   centroid: tuple[float, float]) -> None:
        """Leader: check ``goal`` at the door (the world's extent, finite numbers, the route's
        length: ``goals_refused``), then its stamp and the Navigator's rules (``rejected``)."""
        why = goal_problem(goal.x, goal.y, goal.heading, goal.waypoints, self.extent)
        if why is not None:
            self.counts.goals_refused += 1
            nav.refusal = why[:MAX_REASON]
        else:
            why = None if lockstep else stamp_problem(goal.stamp, stamp)
            if why is not None:
                nav.refuse(why, goal)
            else:
                why = nav.accept(goal, stamp if lockstep else goal.stamp, centroid, self.shapes)
        if why is None:
            self.counts.goals += 1
            if self.routes is not None:
                self.routes.new_goal(nav.goal, nav.heading, centroid, bool(goal.waypoints))
            new = nav.plan(stamp)
            self.follower.adopt(new)
            self.put_plan(new, stamp)
            logger.info("%s: formation %s takes goal (%.3f, %.3f), route of %d",
                        self.cfg.robot_id, self.cfg.formation, goal.x, goal.y, len(new.route))
        elif why != SAME_GOAL:
            logger.warning("%s: refused a goal: %s", self.cfg.robot_id, why)

    def report(self, stamp: float, stalled: bool, stopped: bool) -> None:
        """Leader, after each tick (``stopped``: it commanded zero for missing inputs): publish
        the status if one is due."""
        self.stopped = stopped
        if self.navigator is None or stamp - self._sent.status_at < STATUS_PERIOD_S:
            return
        self._publish_status(self.status_now(stamp, self._centroid, stalled=stalled))

    def status_now(self, stamp: float, centroid: tuple[float, float], stalled: bool = False,
                stopped: bool = False) -> StatusMsg:
        assert self.navigator is not None
        if not (math.isfinite(centroid[0]) and math.isfinite(centroid[1])):
            centroid = self.follower.route[self.follower.index]
        boxed = self.routes is not None and self.routes.replanner.boxed_in
        return self.navigator.status(self.follower, centroid, stalled or boxed,
                                     stopped or self.stopped, stamp, refused=self.counts.goals_refused)

    def _publish_status(self, status: StatusMsg) -> None:
        data = encode_nav(status)
        self._sent.status_bytes = data
        self._sent.status_at = status.stamp
        pub = self._pubs.get(self.keys.status)
        if pub is not None:
            pub.put(data)

    def put_plan(self, plan: PlanMsg, stamp: float) -> None:
        self._sent.plan_at = stamp
        pub = self._pubs.get(self.keys.plan)
        if pub is not None:
            pub.put(encode_nav(plan))

    def stats(self) -> dict[str, Any]:
        c = self.counts
        return {"goals": c.goals, "rejected": self.rejected, "plans": c.plans, "dropped": c.dropped,
                "goals_refused": c.goals_refused}

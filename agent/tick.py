"""One control tick of an agent (:class:`Ticker`), the same coroutine in lock-step and real time.

A tick, for the pose stamped ``t``:

1. publish ``state`` = (own control point, velocity certified by the previous tick, ``t``) (the
   clock says when: lock-step before the command, real time after it);
2. leader: estimate the ellipse from every member's ``state`` (its own from itself), publish it on
   ``ellipse`` (reduced topology), then publish ``others`` = the other leaders' ellipses + its own
   (:class:`agent.leader_step.LeaderPart`);
3. if any input is stale (pose, a neighbour's state, ``others``, ``obstacles``; older than
   ``stale_after``), or a leader misses another formation's ellipse: command zero, count
   ``stale``; otherwise walk the route (:class:`agent.navigation.NavPart`), run
   the controller (:meth:`agent.control.Controller.step`) and publish ``cmd`` stamped ``t``.

The ticker owns the tick's memory (the last certified velocity and pose stamp, the jam rule's
state, the obstacle memory) and its counters (:class:`TickCounts`); the commands go out through
:class:`agent.transport.CommandOut`. A tick that raises is answered with the zero command and
counted (``tick_errors``).
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from agent import double_integrator
from agent.barriers import Obstacle
from agent.body import SHARED_TWISTS
from agent.clock import STATS_WINDOW, Clock
from agent.config import AgentConfig
from agent.control import Controller, Stall, StepResult
from agent.hard_rows import HardRowCounter
from agent.inbox import Inbox
from agent.inputs import carry_pose, others_view, parked_of, step_inputs, with_parked
from agent.leader_step import LeaderPart
from agent.margins import carried_age
from agent.navigation import STALLED_AFTER_S, NavPart
from agent.odom_in import OdomIn
from agent.plausibility import (
    ObstacleMemory,
    held_obstacle,
    listed_obstacles,
    rival_obstacles,
    shapes_of_all,
)
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED, make_solver
from agent.tick_times import COMMAND, INPUTS, LEADER, POSE, RECORD, ROUTE, STATE, STEP, TickTimes
from agent.transport import CommandOut
from agent.unicycle import control_point
from wire import keys
from wire.payloads import Cmd, Obstacles, Others, Pose, ShapeMsg, State, new_cmd, new_state
from wire.stamps import check_stamp

logger = logging.getLogger(__name__)

STATUS_STALE = "stale"  # trace status of a tick that commanded zero for stale inputs
IMPLAUSIBLE = "implausible"  # stale_why: a tick that commanded zero after an implausible input
CONTESTED = "contested"  # stale_why: zero, no state: the pose had a second source (agent.inbox)
POSE_AT_SEND = "pose_at_send"  # stale_why: the pose went stale while the command was computed
TRACE_COLUMNS = ("t", "px", "py", "ux", "uy", "v", "omega", "status", "slack",
                 "h_formation", "h_obstacle", "h_formations", "solve_us")
States = dict[str, State]
Kins = dict[str, tuple[float, float, float, float, float]]  # key -> x, y, ux, uy, theta (clock.align)


@dataclass(frozen=True)
class NodeKeys:
    """The keys one agent publishes and reads (:func:`node_keys`)."""

    pose: str
    state: str
    cmd: str
    others: str
    obstacles: str
    all_to_all: bool
    neighbours: dict[str, Any]  # a graph neighbour's state key -> its desired offset
    foreign: tuple[str, ...]  # the other formations' robots' state keys (all-to-all)
    partners: tuple[str, ...]  # separation rows: every other member, then foreign robots
    states: tuple[str, ...]  # every robot's state this node reads each tick


def node_keys(cfg: AgentConfig) -> NodeKeys:
    """The keys of the agent of ``cfg`` (built once, not per tick)."""
    p = cfg.prefix
    all_to_all = cfg.topology == "all-to-all"
    neighbours = {keys.state_key(p, n): df for n, df in cfg.neighbours}
    foreign = tuple(keys.state_key(p, r) for r in cfg.foreign_robots)
    partners = tuple(keys.state_key(p, r) for r in cfg.partners)
    extra = tuple(k for k in partners if k not in neighbours)
    states = tuple(neighbours) + extra + (foreign if all_to_all else ())
    return NodeKeys(keys.pose_key(p, cfg.robot_id), keys.state_key(p, cfg.robot_id),
                    keys.cmd_key(p, cfg.robot_id), keys.others_key(p, cfg.formation),
                    keys.obstacles_key(p), all_to_all, neighbours, foreign, partners, states)


@dataclass
class TickCounts:
    """What the tick counts (gathered into :class:`agent.stats.AgentStats` by the node)."""

    ticks: int = 0
    stale: int = 0
    waiting: int = 0  # ticks before the first pose arrived (zero command, not stale)
    stale_why: dict[str, int] = field(default_factory=dict)  # stale ticks by the stale input
    solves: int = 0
    escape_ticks: int = 0  # ticks whose nominal was the formation-level escape
    obstacle_held_ticks: int = 0  # ticks that avoided an obstacle missing from the list
    status_counts: dict[str, int] = field(default_factory=lambda: {
        STATUS_RELAXED: 0, STATUS_FALLBACK: 0, STATUS_FAILED: 0})
    min_h: dict[str, float] = field(default_factory=lambda: {
        "formation": math.inf, "obstacle": math.inf, "formations": math.inf})
    solve_us: deque[float] = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # [us]
    trace: list[tuple] = field(default_factory=list)
    tick_errors: int = 0  # ticks that raised: answered with the zero command
    error_kinds: set[str] = field(default_factory=set)  # exception type + where, logged once


@dataclass
class TickParts:
    """What a tick reads and drives, owned elsewhere: the clock, the inbox, the leader's and
    the navigation's parts, and the command output."""

    clock: Clock
    inbox: Inbox
    leader: LeaderPart
    nav: NavPart
    out: CommandOut


class Ticker:
    """The tick of one agent and the tick's memory (module docstring)."""

    def __init__(self, cfg: AgentConfig, node_keys: NodeKeys, parts: TickParts, tolerance: float,
                 trace: bool) -> None:
        self.cfg = cfg
        self.keys = node_keys
        self.parts = parts
        self.clock = parts.clock
        self.tolerance = tolerance  # [s] how far a pose stamp may be off the clock
        self.trace = trace  # keep one row per tick (TRACE_COLUMNS)
        self.counts = TickCounts()
        self.obstacle_memory = ObstacleMemory()
        self.hard = HardRowCounter()  # ticks on which a hard row was not met
        # built once: the config's QP solver (exact by default), the QP timed for solve_us; the
        # formation twists the process's agents share (an agent host's members of a formation
        # solve their formation's QP once a tick: a pure cache, agent.body.TwistMemo)
        self.controller = Controller(cfg.control, make_solver(cfg.solver), time.perf_counter_ns,
                                     twists=SHARED_TWISTS)
        self.after: Callable[[StepResult | None], None] | None = None  # after every tick
        self.times = TickTimes()  # the tick's parts, timed (begun and ended by the scheduler)
        # the tick's memory
        self.last_u = (0.0, 0.0)
        self.last_stamp = 0.0
        self._last_pose_used: float | None = None
        self._stall = Stall()  # this member's copy of its formation's jam state
        self._parked: frozenset[str] = frozenset()  # other formations parked at their goals
        self._tick_point: tuple[float, float, float, float] | None = None
        self._ahead = 0.0  # [s] this tick's pose carried forward by its measured age (carried)
        self._inputs_of: dict[bool, list[tuple[str, str]]] = {}  # leading? -> _tick_inputs
        self.loc: OdomIn | None = None  # controller.localisation fused (set by the node)
        # a fleet robot (set by the node, agent.lifepart): told each tick's pose before the
        # step, True to stand still this tick; and the resting loads, added to the walls
        self.before: Callable[[Pose], bool] | None = None
        self.extra_shapes: Callable[[], tuple[ShapeMsg, ...]] | None = None
        self._standing = False

    def regroup(self, cfg: AgentConfig, node_keys: NodeKeys) -> None:
        """Between ticks: tick in the formation of ``cfg`` from now on (its keys ``node_keys``);
        the jam rule's memory starts afresh, the robot's own memory (velocity, stamps) stays."""
        self.cfg = cfg
        self.keys = node_keys
        self._stall = Stall()
        self._inputs_of.clear()

    async def tick(self, t: float | None) -> StepResult | None:
        """One control tick; ``t`` is the frame's stamp in lock-step, None in real time (only
        the clock reads it). The clock decides when ``state`` goes out: lock-step before the
        command (the neighbours and the leader wait for it), real time after it, with the
        velocity just certified (zero after a stale tick), the freshest it can share."""
        self.counts.ticks += 1
        self._tick_point = None
        try:
            res = await self._tick(t)
            if self.after is not None:  # viewers' diagnostics: a few a second, not counted
                self.after(res)
            self.times.lap(RECORD)
            return res
        except Exception as exc:  # noqa: BLE001 - no message may make an agent raise
            self._tick_failed(t, exc)
            return None
        finally:
            self.clock.state_after(self._send_state)
            self.times.lap(STATE)

    def _tick_failed(self, t: float | None, exc: Exception) -> None:
        """A tick that raised: counted (``tick_errors``), answered with the zero command and
        logged once per kind (exception type and where it was raised), not once per tick."""
        c = self.counts
        c.tick_errors += 1
        frame = traceback.extract_tb(exc.__traceback__)[-1:] or None
        where = f"{frame[0].filename}:{frame[0].lineno}" if frame else "?"
        kind = f"{type(exc).__name__} at {where}"
        if kind not in c.error_kinds:
            c.error_kinds.add(kind)
            logger.error("%s: a tick raised %s: %s (answered with the zero command; logged "
                         "once per kind)", self.cfg.robot_id, kind, exc)
        self._tick_point = None
        self.last_u = self._halted()
        try:
            self.parts.out.send_command(Cmd(0.0, 0.0, 0.0, 0.0,
                                            self.clock.cmd_stamp(t, self.last_stamp)))
        except Exception:  # the zero command itself failed: logged, go on
            logger.debug("%s: zero command after a tick error failed", self.cfg.robot_id,
                         exc_info=True)

    def _halted(self) -> tuple[float, float]:
        """This robot's velocity one period after a zero command: zero, or for a double
        integrator what one period of braking leaves (the world brakes it so:
        :func:`agent.double_integrator.brake`)."""
        c = self.cfg.control
        if not c.double_integrator:
            return (0.0, 0.0)
        vx, vy = self.last_u
        ax, ay = double_integrator.brake(vx, vy, c.max_accel or math.inf, c.period)
        _, _, vx, vy = double_integrator.integrate(0.0, 0.0, vx, vy, ax, ay, c.period, c.max_speed)
        return (vx, vy)

    def _send_state(self) -> None:
        transport = self.parts.out.transport
        if self._tick_point is not None and transport is not None:
            px, py, stamp, th = self._tick_point
            ux, uy = self.last_u
            transport.publish(self.keys.state, new_state(px, py, ux, uy, stamp, th)
                              if self.loc is None else self.loc.state(px, py, self.last_u,
                                                                      stamp, th))

    async def _tick(self, t: float | None) -> StepResult | None:
        """The pose part of the tick: which pose, if any, it runs on."""
        clock, inbox = self.clock, self.parts.inbox
        if clock.lockstep:  # a real-time clock never waits (agent.clock)
            await clock.start(inbox, [(keys.POSE, self.keys.pose)], t)
            self.times.skip()  # the wait for the frame's pose is no part
        pose_entry = inbox.latest(keys.POSE, self.keys.pose)
        if pose_entry is None:  # not localised yet (start-up): zero, counted apart from stale
            self.counts.waiting += 1
            self.parts.out.send_command(Cmd(0.0, 0.0, 0.0, 0.0, clock.cmd_stamp(t, self.last_stamp)))
            return None
        pose: Pose = pose_entry[0]
        if inbox.contested():  # two sources on the pose: neither is trusted (no state sent)
            return self._zero(t, CONTESTED)
        # lock-step: no pose in this frame (camera dropout); the second check cannot fail (the
        # mailbox keeps stamps in order)
        if not clock.pose_current(pose_entry, t) or check_stamp(
                clock.at(t), pose.stamp, self._last_pose_used, self.tolerance,
                self.cfg.stale_after) is not None:
            return self._zero(t, "pose")
        self._last_pose_used = pose.stamp
        clock.note_pose(pose_entry)
        self.last_stamp = pose.stamp
        pose, self._ahead = self.carried(pose, clock.at(t))
        off = self.cfg.control.offset
        px, py = control_point(pose.x, pose.y, pose.theta, off) if self.cfg.control.unicycle \
            else (pose.x, pose.y)
        self._tick_point = (px, py, pose.stamp + self._ahead, pose.theta)
        clock.state_before(self._send_state)
        self._standing = self.before is not None and self.before(pose)
        self.times.lap(POSE)
        return await self._step(t, pose, px, py)

    async def _step(self, t: float | None, pose: Pose, px: float, py: float
                    ) -> StepResult | None:
        """The rest of the tick, on the pose stamped ``stamp``: the leader's part, the inputs,
        the control step, the command."""
        clock, stamp, leader, nav = self.clock, pose.stamp, self.parts.leader, self.parts.nav
        times = self.times
        others_ready = True
        if leader.leading:
            others_ready = await leader.lead(px, py, stamp, stamp, self.last_u, pose.theta,
                                             nav.follower)
            times.lap(LEADER)
        if clock.lockstep:  # a real-time clock never waits (agent.clock)
            await clock.wait(self.parts.inbox, self._tick_inputs(), stamp)
            times.skip()  # the wait for the inputs is no part
        fresh = self._fresh_inputs(stamp, others_ready)
        if isinstance(fresh, str):
            return self._zero(t, fresh)
        states, obstacles, others_msg = fresh
        obs, shape_msgs = self._obstacles(obstacles, clock.at(stamp), px, py)
        if self.extra_shapes is not None:
            shape_msgs = tuple(shape_msgs) + self.extra_shapes()
        if self.parts.inbox.take_implausible():  # an input broke physics since the last tick
            return self._zero(t, IMPLAUSIBLE)
        shapes = nav.update_shapes(shape_msgs)
        own, others = others_view(others_msg)
        self._parked = parked_of(others_msg)
        if self.loc is not None:  # fused: the radii on the ellipses in view count
            self.loc.hear(others_msg)
        target, waypoint = nav.follower.goal, self.cfg.formation_goal
        if own is not None:  # walk the route (the leader takes new goals first)
            times.lap(INPUTS)
            target, waypoint = nav.step(stamp, clock.lockstep, own.cx, own.cy, own,
                                        (obstacles.obstacles, others_msg.ellipses))
            times.lap(ROUTE)
        return self._control(t, pose, clock.align(states, stamp + self._ahead), obs, shapes, own,
                             target, waypoint, others)

    def carried(self, pose: Pose, now: float) -> tuple[Pose, float]:
        """The pose carried forward by its measured age ``now - stamp``, at most the declared
        latency (``controller.bounds``: :func:`agent.margins.carried_age`), under the last
        certified command; the stamp stays the camera's. Without bounds, and in lock-step (each
        pose is its tick's: age 0, as in the in-process simulator), the pose as it came."""
        ahead = carried_age(now - pose.stamp, self.cfg.control.bounds.latency)
        if ahead <= 0.0 or self.clock.lockstep:
            return pose, 0.0
        x, y, th = carry_pose(pose.x, pose.y, pose.theta, *self.last_u, ahead,
                              self.cfg.control.offset)
        return Pose(x, y, th, pose.stamp), ahead

    def _control(self, t: float | None, pose: Pose, states: Kins, obs: list[Obstacle],
                 shapes: Any, own: Any, target: Any, waypoint: Any, others: Any
                 ) -> StepResult | None:
        """The control step on the tick's inputs (``states``: the neighbours' at the pose's
        stamp, :meth:`agent.clock.Clock.align`), and its command."""
        cfg, stamp, k = self.cfg, pose.stamp, self.keys
        neighbours = []
        for n, df in k.neighbours.items():
            x, y, ux, uy, th = states[n]
            neighbours.append((x, y, ux, uy, df, th))
        follower = self.parts.nav.follower
        inputs = step_inputs(
            neighbours, own, cfg.formation, waypoint, others,
            self._stall, cfg.period,  # the jam rule's memory
            [states[n] for n in k.foreign] if k.all_to_all else None,
            [states[n] for n in k.partners],
            leg=(follower.heading, follower.arriving),
            pose=(pose.x, pose.y, pose.theta), goal=target, obstacles=obs, last_u=self.last_u,
            shapes=shapes, footprint=cfg.footprint)
        inputs = with_parked(inputs, self._parked)
        self._stall = inputs.stall
        times = self.times
        times.lap(INPUTS)
        controller, loc = self.controller, self.loc
        if loc is not None:  # fused: held (zero, counted), else the estimates' margins
            if loc.held is not None:
                return self._zero(t, loc.held)
            latest = self.parts.inbox.latest
            controller = loc.controller(controller, (latest(keys.STATE, n) for n in k.states))
        if self._standing:  # a fleet robot lifting or setting a load down
            self._stand(stamp)
            return None
        res = controller.step(inputs)
        times.lap(STEP)
        if self.clock.gone_stale(stamp):
            return self._zero(t, POSE_AT_SEND)  # never send a command from a pose gone stale
        if self.parts.leader.leading:
            stall = self._stall
            self.parts.nav.report(stamp, stall.still >= STALLED_AFTER_S, False)
        self.parts.out.send_command(
            Cmd(res.v, res.omega, res.ux, res.uy, stamp, res.ax, res.ay)
            if cfg.control.double_integrator else new_cmd(res.v, res.omega, res.ux, res.uy, stamp))
        times.lap(COMMAND)
        self.last_u = (res.ux, res.uy)
        self._record(res, stamp)
        return res

    def _fresh_inputs(self, ts: float, others_ready: bool
                      ) -> tuple[States, Obstacles, Others] | str:
        """Every input of the step if all are fresh (``ts``: the reference stamp, lock-step),
        else the name of the first stale one (the reason counted for the zero command)."""
        clock, latest = self.clock, self.parts.inbox.latest
        # freshness (agent.clock.Clock.fresh) against one reading of the clock for every input
        now, limit = clock.at(ts), clock.stale_after + 1e-9
        states: States = {}
        for k in self.keys.states:
            entry = latest(keys.STATE, k)
            if entry is None or not now - entry[0].stamp <= limit:
                return "state"
            states[k] = entry[0]
        obs_entry = latest(keys.OBSTACLES, self.keys.obstacles)
        if obs_entry is None or not now - obs_entry[0].stamp <= limit:
            return "obstacles"
        if self.parts.leader.leading:
            own_others = self.parts.leader.own_others
            if not others_ready or own_others is None:
                return "ellipse"
            return states, obs_entry[0], own_others
        entry = latest(keys.OTHERS, self.keys.others)
        if entry is None or not now - entry[0].stamp <= limit:
            return "others"
        return states, obs_entry[0], entry[0]

    def _obstacles(self, obstacles: Obstacles, now: float, px: float, py: float
                   ) -> tuple[list[Obstacle], tuple[ShapeMsg, ...]]:
        """The step's obstacles and walls: the newest list's, plus those missing from it but
        seen within the hold time, grown where they can have gone, plus, while a second source
        disagrees with that list, every obstacle (moved on to now) and wall the other source
        reports (agent.plausibility; both counted as held)."""
        memory = self.obstacle_memory
        memory.update(obstacles)
        obs = list(listed_obstacles(obstacles))
        held = memory.held(now)
        rivals = self.parts.inbox.obstacle_rivals()
        if held or rivals:
            self.counts.obstacle_held_ticks += 1
            obs += [held_obstacle(o, age, px, py) for o, age in held]
        if rivals:
            obs += rival_obstacles(rivals, now)
            return obs, shapes_of_all(obstacles, rivals)
        return obs, obstacles.shapes

    def _record(self, res: StepResult, stamp: float) -> None:
        """Count a solved step: statuses, lowest barrier values, hard rows not met, solve time,
        trace row."""
        c = self.counts
        self.hard.add(res)
        c.solves += 1
        c.escape_ticks += res.escape
        c.solve_us.append(res.solve_us)
        if res.status in c.status_counts:
            c.status_counts[res.status] += 1
        c.min_h["formation"] = min(c.min_h["formation"], res.h_formation)
        c.min_h["obstacle"] = min(c.min_h["obstacle"], res.h_obstacle)
        c.min_h["formations"] = min(c.min_h["formations"], res.h_formations)
        if self.trace:
            c.trace.append((stamp, res.px, res.py, res.ux, res.uy, res.v, res.omega, res.status,
                            res.slack, res.h_formation, res.h_obstacle, res.h_formations,
                            res.solve_us))

    def _tick_inputs(self) -> list[tuple[str, str]]:
        """The (class, key) of every input a lock-step tick waits for (made once per role)."""
        leading = self.parts.leader.leading
        inputs = self._inputs_of.get(leading)
        if inputs is None:
            inputs = [(keys.STATE, k) for k in self.keys.states]
            inputs.append((keys.OBSTACLES, self.keys.obstacles))
            if not leading:
                inputs.append((keys.OTHERS, self.keys.others))
            self._inputs_of[leading] = inputs
        return inputs

    def _stand(self, stamp: float) -> None:
        """Stand still this tick (a fleet robot's lift or set-down): the zero command, not
        counted as stale."""
        self.last_u = self._halted()
        self.parts.out.send_command(Cmd(0.0, 0.0, 0.0, 0.0, stamp))

    def _zero(self, t: float | None, why: str) -> StepResult | None:
        """Command zero for a stale input ``why`` (counted); None, the tick's result."""
        c = self.counts
        c.stale_why[why] = c.stale_why.get(why, 0) + 1
        c.stale += 1
        self.last_u = self._halted()
        stamp = self.clock.cmd_stamp(t, self.last_stamp)
        self.parts.out.send_command(Cmd(0.0, 0.0, 0.0, 0.0, stamp))
        if self.parts.leader.leading:
            self.parts.nav.report(stamp, False, True)
        logger.debug("%s: stale %s, zero command", self.cfg.robot_id, why)
        if self.trace:
            nan = math.nan
            c.trace.append((stamp, nan, nan, 0.0, 0.0, 0.0, 0.0, STATUS_STALE, 0.0,
                            nan, nan, nan, nan))
        return None

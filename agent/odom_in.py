"""The agent's own pose under ``controller.localisation: fused``, in the agent process.

The world (or a robot's base) publishes the robot's wheel odometry on ``robot/{id}/odom``
(:mod:`wire.odom`) every control period, and the camera its pose on ``robot/{id}/pose``
stamped when the frame was captured. :class:`OdomIn` keeps the camera's poses as they come and,
on each odometry message, runs the robot's filter (:class:`agent.localisation.Localiser`, the
one the in-process simulator runs): the odometry increment first, then every camera pose
received since, each fused at its capture stamp. The filter's estimate, stamped as the
odometry, is the pose the tick drives on: :class:`FusedFeed` hands it to the inbox as the
robot's pose, so the tick, its clocks and its schedulers run unchanged (lock-step: the tick of
frame ``t`` waits for the estimate stamped ``t``; real time: the estimate's arrival ticks).

* A robot that starts unseen has no estimate: it is handed its start pose and waits (zero
  command, counted ``waiting_ticks``) until its first camera pose, as in process. An agent that
  joins a run under way (restarted: its first odometry spans a period, where a run's first is
  empty) does not know where it stands: it hands no pose, so it sends no state, until then.
* Past :data:`agent.margins.RADIUS_LIMIT` the robot commands zero, counted ``over_limit_ticks``;
  its state still goes out (its neighbours see where it stands, with its radius).
* The estimate's confidence radius goes into the robot's ``state`` (``sigma``; a leader puts
  its formation's largest on its ellipse), and every barrier keeps the margin its own and the
  heard radii need (:func:`agent.margins.heard_radius` over its members' states and the
  ellipses of its ``others`` view, :func:`agent.margins.localisation_bounds` through
  :class:`MarginControllers`).
* A malformed odometry or camera payload is dropped and counted (``dropped``); an odometry
  message stamped no later than the last one is refused and counted (``older``).
* Behind a ROS 2 base (:meth:`OdomIn.use_ros_base`) the odometry is the base's own
  ``nav_msgs/msg/Odometry`` on its ``odom`` topic (:func:`agent.base.base_odom_key`): poses in
  the odometry frame, which :class:`RosOdom` differences into the same increments, stamped
  with the message's header stamp. The first is the reference (an empty increment, as a
  world's first); a step or turn larger than the base can make in the elapsed time (a reset of
  the odometry, a jump) is dropped, counted (``odom_jumps``) and becomes the new reference.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from agent import margins
from agent.control import Controller
from agent.localisation import Localiser
from agent.plausibility import JUMP_MARGIN_M, SPEED_FACTOR, jump_ok
from wire import keys
from wire.odom import Odom, body_increment, decode_odom, odom_key
from wire.payloads import Others, Pose, State, decode_pose, encode
from wire.reader import DecodeError
from wire.rmw_zenoh import Odometry, decode_odometry

PENDING = 64  # camera poses kept between two odometry messages (a flood keeps the newest)
HELD_WAITING = "localising"  # stale_why: waiting for the first camera pose
HELD_SIGMA = "sigma"  # stale_why: the confidence radius is past the limit
NAN = math.nan
JUMP_TURN_MARGIN = 0.05  # [rad] a base's heading may turn this much more (noise, rounding)


def ros_increment(ref: Odometry, msg: Odometry, speed: float, turn_rate: float) -> Odom | None:
    """The odometry increment from the base's pose ``ref`` to ``msg`` (both in its odometry
    frame, ``msg`` stamped later), or None where the base cannot have moved so far in the
    elapsed time at ``speed`` [m/s] and ``turn_rate`` [rad/s] (a reset or a jump)."""
    if not jump_ok(ref.x, ref.y, ref.stamp, msg.x, msg.y, msg.stamp, SPEED_FACTOR * speed,
                   JUMP_MARGIN_M):
        return None
    dx, dy, dth = body_increment((ref.x, ref.y, ref.yaw), (msg.x, msg.y, msg.yaw))
    if abs(dth) > SPEED_FACTOR * turn_rate * (msg.stamp - ref.stamp) + JUMP_TURN_MARGIN:
        return None
    try:
        return Odom(dx, dy, dth, ref.stamp, msg.stamp)
    except ValueError:  # beyond what one odometry message carries
        return None


@dataclasses.dataclass
class RosOdom:
    """A ROS 2 base's odometry poses into increments (module docstring): ``speed`` [m/s] and
    ``turn_rate`` [rad/s] are the most the base can do (:func:`agent.base.base_limits`)."""

    speed: float
    turn_rate: float
    ref: Odometry | None = None
    jumps: int = 0

    def step(self, msg: Odometry) -> Odom | None:
        """The increment since the reference (empty at the first); None: a jump, counted (the
        caller refuses a message stamped no later than the reference before this)."""
        ref, self.ref = self.ref, msg
        if ref is None:
            return Odom(0.0, 0.0, 0.0, msg.stamp, msg.stamp)
        inc = ros_increment(ref, msg, self.speed, self.turn_rate)
        self.jumps += inc is None
        return inc


class MarginControllers:
    """One controller per margin the estimates need: ``base`` with the bounds
    :func:`agent.margins.localisation_bounds` gives, built on first use and keyed by
    :func:`agent.margins.margin_steps` (equal steps, equal bounds)."""

    def __init__(self) -> None:
        self._by_steps: dict[tuple[int, int], Controller] = {}

    def get(self, base: Controller, own: float, other: float) -> Controller:
        """The controller for a robot of confidence radius ``own`` hearing ``other``."""
        key = (id(base), margins.margin_steps(own, other))
        got = self._by_steps.get(key)
        if got is None:
            params = base.params
            bounds = margins.localisation_bounds(params.bounds, own, other)
            got = Controller(dataclasses.replace(params, bounds=bounds), base.solve, base.clock,
                             base.tuning)
            self._by_steps[key] = got
        return got


class OdomIn:
    """One robot's odometry, camera poses and filter in its agent (module docstring)."""

    def __init__(self, robot_id: str, prefix: str, start: tuple[float, float, float] | None,
                 period: float, lockstep: bool) -> None:
        self.odom_key = odom_key(prefix, robot_id)
        self.pose_key = keys.pose_key(prefix, robot_id)
        self.start = start
        self.period = period
        self.lockstep = lockstep  # lock-step: each increment spans one period exactly
        self.filter = Localiser()
        self.pending: deque[Pose] = deque(maxlen=PENDING)
        self.last_odom = -math.inf
        self.last_camera = -math.inf  # the newest camera stamp taken to the filter
        self.unseen_since: float | None = None  # [s] that stamp, or the first odometry's
        self.radius = 0.0  # [m] the estimate's confidence radius (0 before the first)
        self.formation_radii: tuple[float | None, ...] = ()  # on this tick's others' ellipses
        self.held: str | None = None  # why the latest estimate commands zero (None: it does not)
        self.controllers = MarginControllers()
        self.counts = {"held_ticks": 0, "over_limit_ticks": 0, "disputed_ticks": 0,
                       "waiting_ticks": 0}
        self.dropped = {"odom": 0, "pose": 0}
        self.older = 0
        self.ros: RosOdom | None = None  # a ROS 2 base's odometry (use_ros_base)
        self.max_radius = 0.0
        self.blind_s = 0.0
        self.trace: list[tuple[float, float, float, float]] = []  # stamp, est_x, est_y, sigma

    # --- inputs ---------------------------------------------------------------------------

    def on_camera(self, payload: bytes) -> None:
        """A camera pose's payload: kept for the next odometry message."""
        try:
            self.pending.append(decode_pose(payload))
        except DecodeError:
            self.dropped["pose"] += 1

    def use_ros_base(self, key: str, speed: float, turn_rate: float) -> None:
        """Take the odometry from a ROS 2 base's ``odom`` topic on ``key`` (nav_msgs/Odometry,
        :class:`RosOdom`) instead of the world's ``odom`` key."""
        self.odom_key = key
        self.ros = RosOdom(speed, turn_rate)

    def on_odom(self, payload: bytes) -> Pose | None:
        """An odometry payload: the filter predicts over it and fuses the camera poses kept
        since (each at its capture stamp, once, in stamp order); the pose the tick drives on,
        stamped as the odometry (None: dropped, or a robot with no start waiting)."""
        if self.ros is not None:
            return self._on_ros_odom(payload, self.ros)
        try:
            m = decode_odom(payload)
        except DecodeError:
            self.dropped["odom"] += 1
            return None
        return self._take(m)

    def _on_ros_odom(self, payload: bytes, ros: RosOdom) -> Pose | None:
        """A ROS 2 base's nav_msgs/Odometry payload, differenced (:class:`RosOdom`), then as
        :meth:`on_odom`."""
        try:
            msg = decode_odometry(payload)
        except ValueError:
            self.dropped["odom"] += 1
            return None
        if ros.ref is not None and msg.stamp <= ros.ref.stamp:
            self.older += 1
            return None
        m = ros.step(msg)
        return None if m is None else self._take(m)

    def _take(self, m: Odom) -> Pose | None:
        """One odometry increment into the filter (:meth:`on_odom`)."""
        if m.stamp <= self.last_odom:
            self.older += 1
            return None
        self.last_odom = m.stamp
        if self.unseen_since is None:
            self.unseen_since = m.stamp
            if m.since != m.stamp:  # joined a run under way (a restart): not at its start
                self.start = None
        dt = self.period if self.lockstep else m.stamp - m.since
        self.filter.odometry(m.stamp, (m.dx, m.dy, m.dtheta), dt)
        self._fuse_pending(m.stamp)
        return self._hand(m.stamp)

    def _fuse_pending(self, now: float) -> None:
        """Every kept camera pose stamped after the last one taken and by ``now`` to the
        filter (a later one waits for its odometry)."""
        later: list[Pose] = []
        for z in sorted(self.pending, key=lambda p: p.stamp):
            if z.stamp > now + 1e-9:
                later.append(z)
            elif z.stamp > self.last_camera:
                self.last_camera = z.stamp
                self.unseen_since = z.stamp
                self.filter.camera(z.stamp, (z.x, z.y, z.theta))
        self.pending.clear()
        self.pending.extend(later)

    def _hand(self, stamp: float) -> Pose | None:
        """The pose handed to the tick at ``stamp`` and whether it is held (counted)."""
        assert self.unseen_since is not None
        self.blind_s = max(self.blind_s, stamp - self.unseen_since)
        est = self.filter.estimate()
        if est is None:
            self.held = HELD_WAITING
            self.counts["waiting_ticks"] += 1
            self.counts["held_ticks"] += 1
            self.trace.append((stamp, NAN, NAN, NAN))
            if self.start is None:
                return None
            return Pose(self.start[0], self.start[1], self.start[2], stamp)
        (x, y, th), r = est
        self.radius = r
        over = r > margins.RADIUS_LIMIT
        self.held = HELD_SIGMA if over else None
        self.counts["over_limit_ticks"] += over
        self.counts["held_ticks"] += over
        self.counts["disputed_ticks"] += self.filter.disputed
        self.max_radius = max(self.max_radius, r)
        self.trace.append((stamp, x, y, r))
        return Pose(x, y, th, stamp)

    # --- what the tick reads --------------------------------------------------------------

    def hear(self, others: Others) -> None:
        """This tick's ``others`` message: the radii on its ellipses (the formations in view
        and its own) count in :meth:`controller`."""
        own = () if others.own is None else (others.own.sigma,)
        self.formation_radii = (*own, *(e.sigma for e in others.ellipses))

    def controller(self, base: Controller, heard: Iterable[Any]) -> Controller:
        """The controller of this tick: ``base`` with the margins this robot's radius and the
        largest it hears need (:func:`agent.margins.heard_radius` over the ``heard`` states'
        and :meth:`hear`'s ellipses')."""
        other = margins.heard_radius(
            self.radius, (None if entry is None else entry[0].sigma for entry in heard),
            self.formation_radii)
        return self.controllers.get(base, self.radius, other)

    def formation_radius(self, members: Iterable[Any]) -> float:
        """A leader's formation's largest confidence radius, for its ellipse: its own and its
        ``members``' latest states' (inbox entries, None: none yet)."""
        return margins.heard_radius(
            self.radius, (None if entry is None else entry[0].sigma for entry in members), ())

    def state(self, px: float, py: float, u: tuple[float, float], stamp: float,
              theta: float) -> State:
        """This robot's ``state`` with its confidence radius."""
        return State(px, py, u[0], u[1], stamp, theta, self.radius)

    def stats(self) -> dict[str, Any]:
        """The agent's ``localisation`` counters (agent.stats; its trace's rows: stamp, est_x,
        est_y, sigma_m, None where the robot had no estimate)."""
        f = self.filter
        jumps = {} if self.ros is None else {"odom_jumps": self.ros.jumps}
        return {"rejected": f.rejected, "fused": f.fused, "relocalised": f.relocalised,
                "max_sigma_m": self.max_radius, "blind_s": self.blind_s, **self.counts,
                "dropped": dict(self.dropped), "older": self.older, **jumps,
                "trace": [[v if math.isfinite(v) else None for v in row] for row in self.trace]}


class FusedFeed:
    """The odometry and camera subscribers' callbacks (on Zenoh's threads): into
    :class:`OdomIn`, and its estimate into the inbox as the robot's pose.

    ``tick``: real time on pose arrival, the scheduler's feed (stores under the tick lock and
    ticks, :meth:`agent.schedule.PoseScheduler.feed`); None: the event loop's (lock-step, or
    a clock-driven agent), where the samples are handed over in the order they came."""

    def __init__(self, odom_in: OdomIn, inbox: Any, loop: asyncio.AbstractEventLoop,
                 tick: Callable[[Callable[[], object]], None] | None, lock: Any) -> None:
        self.odom_in = odom_in
        self.inbox = inbox
        self.loop = loop
        self.tick = tick
        self.lock = lock

    def odom(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        if self.tick is not None:
            self.tick(lambda: self._offer(payload))
            return
        try:
            self.loop.call_soon_threadsafe(self._offer_on_loop, payload)
        except RuntimeError:  # loop closed: shutting down
            pass

    def camera(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        if self.tick is not None:
            with self.lock:
                self.odom_in.on_camera(payload)
            return
        try:
            self.loop.call_soon_threadsafe(self.odom_in.on_camera, payload)
        except RuntimeError:  # loop closed: shutting down
            pass

    def _offer(self, payload: bytes) -> bool:
        """The estimate of odometry ``payload`` into the inbox as the pose; True if one."""
        pose = self.odom_in.on_odom(payload)
        if pose is None:
            return False
        self.inbox.offer(keys.POSE, self.odom_in.pose_key, encode(pose))
        return True

    def _offer_on_loop(self, payload: bytes) -> None:
        if self._offer(payload):  # stored on the loop's next pass: wake the tick after it
            self.loop.call_soon(self.inbox.on_arrival, self.odom_in.pose_key)

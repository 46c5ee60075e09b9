"""Localisation in the in-process simulator: what each robot's agent is handed when the camera
cannot see it, and under ``controller.localisation: fused`` its own filter's estimate.

Built only for a scenario with blind floor, camera faults or ``fused`` (:meth:`FleetLocalisation.build`);
every other run never reaches this module and stays as it was, byte for byte.

Each tick (:meth:`FleetLocalisation.sense`): every robot's wheel odometry since the last tick
(:class:`simulator.odometry.Odometer`) and the camera's pose of it, unless it stood on blind
floor when the frame was captured or an injected fault (``world.camera_faults``) hides or
falsifies it.

* ``camera``: a robot without a pose keeps its last one and commands zero (its pose is stale,
  as an agent does); one never seen waits.
* ``fused``: each robot's :class:`agent.localisation.Localiser` takes the odometry and each new
  camera pose at its capture stamp; the robot drives on the filter's pose (which its ``state``
  then carries to its neighbours and leader, and its leader's ellipse, as its formation's
  largest radius, to the other formations), every barrier keeps the margin its and the
  others' confidence radii need (:func:`agent.margins.localisation_bounds` with
  :func:`agent.margins.heard_radius`, the agents' rule), and past
  :data:`agent.margins.RADIUS_LIMIT` it stops, counted. It waits for its first camera pose.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from agent import margins, unicycle
from agent.control import Controller, StepResult
from agent.localisation import Localiser
from agent.odom_in import MarginControllers
from scenario import Scenario
from scenario.world import CameraFault, blind_at

from .lab import LabWorld
from .odometry import Odometer

HELD = "stale"  # robots.csv status of a tick held at zero for want of a pose
INF = math.inf
NAN = math.nan

Pose = tuple[float, float, float]


def fault_pose(f: CameraFault, i: int, ids: Sequence[str], seen: Sequence[Sequence[float]]
               ) -> Pose | None | bool:
    """What fault ``f`` makes of robot ``i``'s camera pose: None (lost), a wrong pose, or True
    (the fault does not touch it)."""
    if f.kind == "outage":
        return None
    if ids[i] != f.robot:
        return True
    if f.kind == "misread":
        o = seen[ids.index(f.other)]
        return (o[0], o[1], o[2])
    s = seen[i]
    return (s[0] + f.offset[0], s[1] + f.offset[1], s[2])


def apply_faults(faults: Sequence[CameraFault], stamp: float, ids: Sequence[str],
                 seen: Sequence[Sequence[float]], out: list[Pose | None]) -> list[Pose | None]:
    """``out`` (each robot's camera pose of the frame captured at ``stamp``, None where the
    camera sees nothing) under the injected ``faults`` active then (:func:`fault_pose`;
    ``seen``: every robot's pose as the camera measured it, blind or not)."""
    for f in faults:
        if not f.active(stamp):
            continue
        for i in range(len(out)):
            got = fault_pose(f, i, ids, seen)
            if got is not True and out[i] is not None:
                out[i] = got if isinstance(got, tuple) else None
    return out


def formation_radii(radius: Sequence[float], membership: np.ndarray) -> np.ndarray:
    """Each formation's largest confidence radius among its members (what its leader puts on
    its ellipse: :func:`leader.role.ellipse_to_msg`)."""
    r = np.asarray(radius, dtype=float)
    return np.max(np.where(membership > 0, r[:, None], 0.0), axis=0)


def zero_result(pose: Sequence[float], offset: float) -> StepResult:
    """The zero command of a robot held for want of a pose (no QP solved)."""
    px, py = unicycle.control_point(pose[0], pose[1], pose[2], offset)
    return StepResult(0.0, 0.0, 0.0, 0.0, px, py, HELD, 0.0, INF, INF, INF, 0.0, 0.0, 0.0)


class FleetLocalisation:
    """Every robot's view of its own pose in one in-process run (see the module docstring)."""

    def __init__(self, scenario: Scenario, lab: LabWorld | None) -> None:
        self.scenario = scenario
        self.lab = lab
        self.fused = scenario.controller.localisation == "fused"
        self.ids = scenario.robot_ids
        names = [f.name for f in scenario.formations]
        self.membership = np.array([[scenario.formation_of(rid).name == f for f in names]
                                    for rid in self.ids], dtype=float)  # (robots, formations)
        self.formation_of = [names.index(scenario.formation_of(rid).name) for rid in self.ids]
        self.column = {f: j for j, f in enumerate(names)}
        self.per_formation: np.ndarray | None = None  # this tick's formation_radii (first use)
        n = len(self.ids)
        self.odometer = Odometer(scenario.world, n)
        self.filters = [Localiser() for _ in range(n)] if self.fused else []
        self.truth: list[Pose] | None = None  # the last tick's true poses
        self.handed: list[Pose | None] = [None] * n  # the pose each agent drives on
        self.radius = [0.0] * n  # [m] each estimate's confidence radius (fused)
        self.held = [False] * n  # this tick: zero command (no pose, waiting, over the limit)
        self.last_stamp = [-INF] * n
        self.unseen_since = [0.0] * n  # [s] when each robot's last camera pose was captured
        self.controllers = MarginControllers()
        self.counts = {"held_ticks": 0, "over_limit_ticks": 0, "disputed_ticks": 0,
                       "waiting_ticks": 0}
        self.max_error = 0.0
        self.max_radius = 0.0
        self.blind_s = 0.0

    @classmethod
    def build(cls, scenario: Scenario, lab: LabWorld | None) -> FleetLocalisation | None:
        """The run's localisation; None where nothing differs from the camera seeing all."""
        w = scenario.world
        if scenario.controller.localisation == "camera" and not w.camera_blind \
                and not w.camera_faults:
            return None
        return cls(scenario, lab)

    # --- each tick ----------------------------------------------------------------------

    def sense(self, k: int, state: Sequence[Sequence[float]],
              seen: Sequence[Sequence[float]]) -> list[Pose]:
        """The poses the agents drive on at tick ``k`` (true poses ``state``, the camera's
        ``seen``); :attr:`held` says which of them command zero."""
        dt = self.scenario.dt
        t = k * dt
        truth = [(s[0], s[1], s[2]) for s in state]
        wheels = self.lab.wheel_increments() if self.lab is not None else None
        if self.fused and self.truth is not None:
            for f, inc in zip(self.filters, self.odometer.increments(self.truth, truth, wheels),
                              strict=True):
                f.odometry(t, inc, dt)
        self.truth = truth
        stamp, captured = self.lab.captured(k) if self.lab is not None else (t, truth)
        poses = self.camera_poses(stamp, captured, seen)
        out = [self.pose_of(i, stamp, z) for i, z in enumerate(poses)]
        self.per_formation = None
        self.blind_s = max([self.blind_s] + [t - u for u in self.unseen_since])
        return out

    def camera_poses(self, stamp: float, captured: Sequence[Sequence[float]],
                     seen: Sequence[Sequence[float]]) -> list[Pose | None]:
        """What the camera hands each robot for the frame captured at ``stamp``: None on blind
        floor or in an outage; a wrong pose under a misread or forged fault."""
        boxes = self.scenario.world.camera_blind
        out: list[Pose | None] = [
            None if blind_at(boxes, c[0], c[1]) else (s[0], s[1], s[2])
            for c, s in zip(captured, seen, strict=True)]
        return apply_faults(self.scenario.world.camera_faults, stamp, self.ids, seen, out)

    def pose_of(self, i: int, stamp: float, z: Pose | None) -> Pose:
        """Robot ``i``'s pose to drive on, from its camera pose ``z`` (None: none)."""
        truth = self.truth
        assert truth is not None
        if z is not None and stamp > self.last_stamp[i]:
            self.last_stamp[i] = stamp
            self.unseen_since[i] = stamp
            if self.fused:
                self.filters[i].camera(stamp, z)
        if not self.fused:
            if z is not None:
                self.handed[i] = z
            self.held[i] = z is None
            return self.pose_or_wait(i)
        est = self.filters[i].estimate()
        if est is None:
            self.held[i] = True
            return self.pose_or_wait(i)
        self.handed[i], self.radius[i] = est[0], est[1]
        over = est[1] > margins.RADIUS_LIMIT
        self.held[i] = over
        self.counts["over_limit_ticks"] += over
        self.counts["disputed_ticks"] += self.filters[i].disputed
        self.max_radius = max(self.max_radius, est[1])
        self.max_error = max(self.max_error, math.hypot(est[0][0] - truth[i][0],
                                                        est[0][1] - truth[i][1]))
        return est[0]

    def pose_or_wait(self, i: int) -> Pose:
        """The last pose handed to robot ``i``; before any, it waits where it starts (its
        neighbours then see its start, where it stands)."""
        got = self.handed[i]
        if got is None:
            self.counts["waiting_ticks"] += 1
            start = self.scenario.robots[i].start
            return (start[0], start[1], start[2])
        return got

    def hold(self, i: int, pose: Sequence[float], offset: float) -> StepResult | None:
        """Robot ``i``'s zero command when it is held this tick (counted), else None."""
        if not self.held[i]:
            return None
        self.counts["held_ticks"] += 1
        return zero_result(pose, offset)

    def controller(self, i: int, base: Controller, in_view: Sequence[str] = ()) -> Controller:
        """The controller robot ``i`` steps with: ``base`` under ``camera``; under ``fused``
        one whose margins hold its own and the others' confidence radii
        (:func:`agent.margins.localisation_bounds` with :meth:`heard_radius`; one per margin,
        :class:`agent.odom_in.MarginControllers`). ``in_view``: the other formations in its
        ``others`` view this tick."""
        if not self.fused:
            return base
        return self.controllers.get(base, self.radius[i], self.heard_radius(i, in_view))

    def heard_radius(self, i: int, in_view: Sequence[str]) -> float:
        """The largest confidence radius robot ``i`` hears (:func:`agent.margins.heard_radius`
        over its formation's radius and those of the formations ``in_view``, as its agent hears
        them on the ellipses of its ``others``)."""
        if self.per_formation is None:
            self.per_formation = formation_radii(self.radius, self.membership)
        radii = self.per_formation
        return margins.heard_radius(
            self.radius[i], (), [float(radii[self.formation_of[i]])]
            + [float(radii[self.column[f]]) for f in in_view])

    # --- what the run records -----------------------------------------------------------

    def true_points(self, results: list[StepResult], state: Sequence[Sequence[float]]
                    ) -> list[StepResult]:
        """``results`` with each control point the true pose's (robots.csv and the formation
        error are measured on the truth, as in a lab world)."""
        off = self.scenario.robot.control_offset
        out = []
        for r, s in zip(results, state, strict=True):
            px, py = unicycle.control_point(s[0], s[1], s[2], off)
            out.append(r._replace(px=px, py=py))
        return out

    def annotate(self, rows: list[tuple]) -> None:
        """The last tick's robots.csv rows gain est_x, est_y, sigma_m (``fused`` only)."""
        if not self.fused:
            return
        n = len(self.ids)
        for j, (h, r) in enumerate(zip(self.handed, self.radius, strict=True)):
            pos = len(rows) - n + j
            x, y = (math.nan, math.nan) if h is None else (h[0], h[1])
            rows[pos] = rows[pos] + (x, y, r if h is not None else math.nan)

    def summary(self) -> dict[str, Any]:
        """summary.json's ``localisation`` block (``fused`` only)."""
        if not self.fused:
            return {}
        return localisation_block(
            self.scenario, (self.max_error, self.max_radius, self.blind_s),
            {"rejected": sum(f.rejected for f in self.filters),
             "fused": sum(f.fused for f in self.filters),
             "relocalised": sum(f.relocalised for f in self.filters)}, self.counts)


def localisation_block(scenario: Scenario, maxima: tuple[float, float, float],
                       filters: dict[str, int], counts: dict[str, int]) -> dict[str, Any]:
    """summary.json's ``localisation`` block of a ``fused`` run, in process or over Zenoh:
    ``maxima`` = (largest error of an estimate from the truth [m], largest confidence radius
    [m], longest stretch unseen [s]), the filters' ``filters`` counts (rejected, fused,
    relocalised) and the held ``counts``."""
    w = scenario.world
    return {"localisation": {
        "max_error_m": round(maxima[0], 6),
        "max_sigma_m": round(maxima[1], 6),
        "blind_s": round(maxima[2], 6),
        **filters,
        "radius_limit_m": margins.RADIUS_LIMIT,
        **counts,
        "odometry": dataclasses.asdict(w.odometry),
        "camera_blind": [dataclasses.asdict(b) for b in w.camera_blind],
    }}


def merge_estimates(scenario: Scenario, rows: Sequence[tuple], stats: Sequence[Any],
                    stamps: Sequence[float]) -> tuple[list[tuple], dict[str, Any]]:
    """A multi-process ``fused`` run: robots.csv's ``rows`` with est_x, est_y, sigma_m from
    each agent's localisation trace (keyed by the stamp of the tick's odometry, ``stamps[k]``;
    NaN where it has none), and summary.json's ``localisation`` block (the error measured on
    those rows' true poses, the rest from the agents' counters)."""
    by_key = {(s.robot, row[0]): row for s in stats if s.localisation
              for row in s.localisation["trace"]}
    dt = scenario.dt
    out, worst = [], 0.0
    for row in rows:
        k = round(row[0] / dt)
        got = by_key.get((row[1], stamps[k])) if k < len(stamps) else None
        est = tuple(NAN if v is None else v for v in got[1:4]) if got is not None else (NAN,) * 3
        if math.isfinite(est[0]):
            worst = max(worst, math.hypot(est[0] - row[3], est[1] - row[4]))
        out.append((*row, *est))
    locs = [s.localisation for s in stats if s.localisation]
    counts = {key: sum(x.get(key, 0) for x in locs)
              for key in ("held_ticks", "over_limit_ticks", "disputed_ticks", "waiting_ticks")}
    filters = {key: sum(x.get(key, 0) for x in locs) for key in ("rejected", "fused", "relocalised")}
    maxima = (worst, max((x["max_sigma_m"] for x in locs), default=0.0),
              max((x["blind_s"] for x in locs), default=0.0))
    return out, localisation_block(scenario, maxima, filters, counts)

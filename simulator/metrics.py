"""Safety and progress measured on true body positions, for ``summary.json``.

The same monitor serves the in-process simulator and the multi-process world, so both report
collisions, clearances and formation error the same way (docs/outputs.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from geometry.shapes import shape_distance
from scenario import Scenario
from scenario.cargo import CONTACT_TOL, LOAD_REACH, load_clearances, load_polygon, loads_now

CONTACT_RELEASE = 1e-3  # [m] a contact ends once the clearance exceeds this (onset hysteresis)
SHAPE_SLACK = 1e-9  # [m] the array filter keeps what rounding could put just inside its bound


class SafetyMonitor:
    """Feed it every tick's body positions; read the summary fields at the end.

    Over 20 attributes on purpose: each running minimum, count and onset memory is one field of
    ``summary.json`` (or what it needs to count once per onset), kept side by side so that every
    tick updates them from one pass over the bodies."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        ids = scenario.robot_ids
        self._index = {rid: k for k, rid in enumerate(ids)}
        self._n = len(ids)
        self._two_r = 2.0 * scenario.robot.radius
        self._edges = np.array(
            [(self._index[e.i], self._index[e.j]) for f in scenario.formations for e in f.edges],
            dtype=int,
        ).reshape(-1, 2)
        self._df = np.array([e.df for f in scenario.formations for e in f.edges])
        self._goals = np.array([r.goal for r in scenario.robots], dtype=float)
        self._iu = np.triu_indices(self._n, 1)
        self._ds = np.array([o.safe_distance for o in scenario.obstacles], dtype=float)
        self._robot_contact = np.zeros(len(self._iu[0]), dtype=bool)
        self._obstacle_contact = np.zeros((self._n, len(self._ds)), dtype=bool)
        self.collisions = 0
        self.collision_log: list[dict] = []
        self.min_clearance_robot = math.inf
        self.min_clearance_obstacle = math.inf
        self._shapes = scenario.shapes
        self._shape_contact = np.zeros((self._n, len(self._shapes)), dtype=bool)
        # each shape's frame (centre, axes, half sizes, Ds): every robot's clearance to every
        # shape in one array pass, a filter before the exact measure of geometry.shapes
        self._shape_frames = np.array([(sh.cx, sh.cy, math.cos(sh.yaw), math.sin(sh.yaw), sh.hx,
                                        sh.hy, sh.ds) for sh in self._shapes]).reshape(-1, 7)
        # the log entry of each contact still going on, by key, for its deepest_m
        self._open: dict[tuple, dict] = {}
        self.min_clearance_shape = dict.fromkeys((sh.name for sh in self._shapes), math.inf)
        self._outlines = [load_polygon(f) for f in scenario.formations]  # loads at the start
        self._load_contact: set[tuple[int, str]] = set()
        self.min_clearance_load = math.inf
        self.formation_error_max = 0.0
        self.time_to_goal: float | None = None
        self.reached = np.zeros(self._n, dtype=bool)
        self._last: np.ndarray | None = None  # the positions of the last update

    def update(self, t: float, positions: np.ndarray, obstacles: Sequence[tuple[float, float]]):
        """``positions``: (n, 2) body centres in scenario robot order; ``obstacles``: centres."""
        pos = np.asarray(positions, dtype=float)
        ids = self.scenario.robot_ids
        if self._n > 1:
            diff = pos[:, None, :] - pos[None, :, :]
            dist = np.sqrt(np.sum(diff * diff, axis=2))[self._iu]
            clear = dist - self._two_r
            self.min_clearance_robot = min(self.min_clearance_robot, float(np.min(clear)))
            onset = (clear < -CONTACT_TOL) & ~self._robot_contact
            for k in np.nonzero(onset)[0]:
                self.collisions += 1
                a, b = ids[self._iu[0][k]], ids[self._iu[1][k]]
                self._log(("r", int(k)), {"t": round(t, 6), "a": a, "b": b,
                                          "clearance_m": float(clear[k])})
            # A pair stays "in contact" until it is clearly apart again, so a pair grazing the
            # limit for a while is one collision, not one per tick.
            self._robot_contact = (clear < -CONTACT_TOL) | (self._robot_contact & (clear <= CONTACT_RELEASE))
            self._deepen("r", clear, self._robot_contact)
        if len(self._ds):
            obs = np.asarray(obstacles, dtype=float).reshape(-1, 2)
            d = np.sqrt(np.sum((pos[:, None, :] - obs[None, :, :]) ** 2, axis=2)) - self._ds
            self.min_clearance_obstacle = min(self.min_clearance_obstacle, float(np.min(d)))
            names = [o.name for o in self.scenario.obstacles]
            onset = (d < -CONTACT_TOL) & ~self._obstacle_contact
            for i, j in zip(*np.nonzero(onset), strict=True):
                self.collisions += 1
                self._log(("o", int(i), int(j)), {"t": round(t, 6), "a": ids[i], "b": names[j],
                                                  "clearance_m": float(d[i, j])})
            self._obstacle_contact = (d < -CONTACT_TOL) | (self._obstacle_contact & (d <= CONTACT_RELEASE))
            self._deepen("o", d, self._obstacle_contact)
        if self._shapes:
            self._update_shapes(t, pos)
        if any(self._outlines):
            self._update_loads(t, pos, obstacles)
        if len(self._df):
            e = pos[self._edges[:, 0]] - pos[self._edges[:, 1]]
            err = np.abs(np.sqrt(np.sum(e * e, axis=1)) - self._df)
            self.formation_error_max = max(self.formation_error_max, float(np.max(err)))
        self._last = pos
        self.reached = self._at_goals(pos)
        if self.time_to_goal is None and bool(np.all(self.reached)):
            self.time_to_goal = t

    def _at_goals(self, pos: np.ndarray) -> np.ndarray:
        gd = np.sqrt(np.sum((pos - self._goals) ** 2, axis=1))
        return gd <= self.scenario.goal_tolerance

    def retarget(self, goals: Sequence[tuple[float, float]], first_at: float | None,
                 end: float) -> None:
        """Judge the run against ``goals`` (every robot's, in scenario order; the goals its
        formation was last sent, :mod:`simulator.goals`) instead of the scenario's: whether the
        last positions checked are at them, and ``time_to_goal`` the first time every robot was
        (``first_at``; ``end``, the run's end, when only the last positions were)."""
        self._goals = np.array(goals, dtype=float)
        if self._last is not None:
            self.reached = self._at_goals(self._last)
        if not self.all_reached:
            self.time_to_goal = None
        else:
            self.time_to_goal = first_at if first_at is not None else end

    def _update_shapes(self, t: float, pos: np.ndarray) -> None:
        """Walls and shelves: clearance = distance from the shape (signed, negative inside a
        box) less Ds, per robot and shape; an intrusion counts like a circle's. Only the pairs
        that can change a field are measured (:meth:`_shape_pairs`)."""
        ids = self.scenario.robot_ids
        for j, i in self._shape_pairs(pos):
            sh = self._shapes[j]
            d = shape_distance(float(pos[i, 0]), float(pos[i, 1]), sh)[0] - sh.ds
            if d < self.min_clearance_shape[sh.name]:
                self.min_clearance_shape[sh.name] = d
            self.min_clearance_obstacle = min(self.min_clearance_obstacle, d)
            inside = d < -CONTACT_TOL
            if inside and not self._shape_contact[i, j]:
                self.collisions += 1
                self._log(("s", i, j), {"t": round(t, 6), "a": ids[i], "b": sh.name,
                                        "clearance_m": float(d)})
            self._shape_contact[i, j] = inside or (self._shape_contact[i, j] and d <= CONTACT_RELEASE)
            self._still(("s", i, j), float(d), bool(self._shape_contact[i, j]))

    def _shape_pairs(self, pos: np.ndarray) -> list[tuple[int, int]]:
        """(shape, robot) of every pair whose clearance can lower its shape's least clearance
        or take part in a contact, shape by shape: those whose clearance, from
        :func:`box_clearances` less :data:`SHAPE_SLACK` for its rounding, is not above both,
        and every pair in contact. The others cannot change any field, so the fields are
        those of measuring every pair."""
        gap = box_clearances(pos, self._shape_frames) - SHAPE_SLACK
        least = np.array([max(self.min_clearance_shape[sh.name], CONTACT_RELEASE)
                          for sh in self._shapes])
        need = (gap <= least) | self._shape_contact
        js, iis = np.nonzero(need.T)
        return list(zip(js.tolist(), iis.tolist(), strict=True))

    def _update_loads(self, t: float, pos: np.ndarray,
                      obstacles: Sequence[tuple[float, float]]) -> None:
        """Each formation's load, placed by the rigid fit of its members' start body
        positions onto ``pos``, against everything but its own members
        (:func:`scenario.cargo.load_clearances`); an overlap counts like a robot's collision,
        logged with ``kind: load``, ``a`` the formation and (x, y) where."""
        loads = loads_now(self.scenario, self._outlines, pos)
        contact: set[tuple[int, str]] = set()
        # what lies beyond both the least clearance yet and a contact's release changes no
        # field: measured out to there only (never beyond cargo's own reach)
        reach = min(LOAD_REACH, max(self.min_clearance_load, CONTACT_RELEASE))
        for c in load_clearances(self.scenario, loads, pos, list(obstacles), reach):
            self.min_clearance_load = min(self.min_clearance_load, c.clearance)
            key = (c.formation, c.other)
            if c.clearance < -CONTACT_TOL and key not in self._load_contact:
                self.collisions += 1
                self._log(("l",) + key, {
                    "t": round(t, 6), "a": self.scenario.formations[c.formation].name,
                    "b": c.other, "clearance_m": c.clearance, "kind": "load",
                    "x": round(c.x, 4), "y": round(c.y, 4)})
            if c.clearance < -CONTACT_TOL or (key in self._load_contact
                                               and c.clearance <= CONTACT_RELEASE):
                contact.add(key)
            self._still(("l",) + key, c.clearance, key in contact)
        for key in [k for k in self._open if k[0] == "l" and k[1:] not in contact]:
            del self._open[key]  # out of reach this tick: apart, so that contact has ended
        self._load_contact = contact

    def _log(self, key: tuple, entry: dict) -> None:
        """A new collision: its log entry (``clearance_m`` at its first tick; ``deepest_m``, the
        least clearance while the contact lasts, is kept up to date)."""
        entry["deepest_m"] = entry["clearance_m"]
        self.collision_log.append(entry)
        self._open[key] = entry

    def _still(self, key: tuple, clearance: float, touching: bool) -> None:
        """One contact's clearance this tick: deepen its entry, or close it once released."""
        entry = self._open.get(key)
        if entry is None:
            return
        if touching:
            entry["deepest_m"] = min(entry["deepest_m"], clearance)
        else:
            del self._open[key]

    def _deepen(self, kind: str, clear: np.ndarray, touching: np.ndarray) -> None:
        """:meth:`_still` for every open contact of one array (robot pairs, or robot x circle)."""
        for key in [k for k in self._open if k[0] == kind]:
            idx = key[1:]
            self._still(key, float(clear[idx]), bool(touching[idx]))

    @property
    def all_reached(self) -> bool:
        return bool(np.all(self.reached))

    def summary_fields(self) -> dict:
        return {
            "all_reached": self.all_reached,
            "time_to_goal_s": None if self.time_to_goal is None else round(self.time_to_goal, 6),
            "collisions": self.collisions,
            "min_clearance_m": {
                "obstacle": _finite_or_none(self.min_clearance_obstacle),
                "robot": _finite_or_none(self.min_clearance_robot),
                "load": _finite_or_none(self.min_clearance_load),
            },
            "formation_error_max_m": self.formation_error_max,
            **({"min_clearance_shape_m": {k: _finite_or_none(v)
                                          for k, v in self.min_clearance_shape.items()}}
               if self._shapes else {}),
        }


def box_clearances(pos: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(n, S): each point's signed distance to each box less its Ds,
    :func:`geometry.shapes.box_distance` in arrays (a segment is the box of half width 0);
    ``frames`` (S, 7): centre, cos and sin of the yaw, half sizes, Ds."""
    dx = pos[:, 0:1] - frames[:, 0]
    dy = pos[:, 1:2] - frames[:, 1]
    c, s = frames[:, 2], frames[:, 3]
    qu = np.abs(c * dx + s * dy) - frames[:, 4]
    qv = np.abs(-s * dx + c * dy) - frames[:, 5]
    outside = np.hypot(np.maximum(qu, 0.0), np.maximum(qv, 0.0))
    inside = np.maximum(qu, qv)
    return np.where((qu > 0.0) | (qv > 0.0), outside, inside) - frames[:, 6]


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None

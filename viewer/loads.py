"""Each formation's load in a frame: where it is and what it overlaps.

A frame (:mod:`viewer.frame`) carries

* ``loads``: ``[{"formation", "outline": [[x, y], ...], "declared": bool}]``, the load each
  formation carries, placed from its members' body positions by
  :func:`scenario.cargo.placed_load` (the formula the figures and the safety monitor use): a
  declared ``load:`` (``declared`` true), or the members' start hull (false; two points for a
  pair). A formation with a member not heard of has none in that frame.
* ``load_hits``: ``[{"formation", "other", "clearance", "line": [[x, y], [x, y]]}]``, every
  overlap of a load with another formation's robot or load, a circle's physical disk, a wall or
  a shelf, as :func:`scenario.cargo.load_clearances` (the safety monitor's function) finds it;
  ``line`` runs from the point of the load's outline nearest the thing to the thing's point
  (a robot's or circle's centre, the wall's, shelf's or other load's point nearest this load's
  centre).

:class:`LoadView` needs the scenario (the members' start positions and declared loads);
without one (``formation view`` of a fleet it was given no scenario for),
:func:`hull_entries` draws each formation's hull of its members' body centres as heard, and
no hits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from geometry.polygon import bounding_circle, closest_point, convex_hull
from scenario.cargo import CONTACT_TOL, LoadContact, load_clearances, load_polygon, placed_load

Point = tuple[float, float]


class LoadView:
    """The ``loads`` and ``load_hits`` of a scenario's frames (see the module docstring)."""

    def __init__(self, scenario: Any) -> None:
        self.scenario = scenario
        self._outlines = [load_polygon(f) for f in scenario.formations]  # at the start
        self._index = {rid: k for k, rid in enumerate(scenario.robot_ids)}
        self._shapes = {sh.name: sh.corners() for sh in scenario.shapes}
        self._names = [f.name for f in scenario.formations]

    def fields(self, robots: Sequence[dict], obstacles: Sequence[dict],
               hits: bool = True) -> dict[str, list]:
        """``{"loads", "load_hits"}`` of a frame's ``robots`` and ``obstacles`` entries;
        ``hits=False``: no overlaps looked for (a run whose loads never overlapped: they cost
        about 10 times what placing the loads costs)."""
        bodies = np.full((len(self._index), 2), math.nan)
        for r in robots:
            k = self._index.get(r["id"])
            if k is not None and r["x"] is not None and r["y"] is not None:
                bodies[k] = (r["x"], r["y"])
        placed = [self._place(f, outline, bodies)
                  for f, outline in zip(self.scenario.formations, self._outlines, strict=True)]
        loads = [{"formation": f.name, "outline": [[x, y] for x, y in poly],
                  "declared": bool(f.load)}
                 for f, poly in zip(self.scenario.formations, placed, strict=True) if poly]
        return {"loads": loads, "load_hits": self._hits(placed, bodies, obstacles) if hits else []}

    def _place(self, f: Any, outline: Sequence[Point], bodies: np.ndarray) -> tuple[Point, ...]:
        if not outline:
            return ()
        pts = bodies[[self._index[r.id] for r in f.robots]]
        if not np.isfinite(pts).all():
            return ()
        return placed_load(f, outline, [(float(x), float(y)) for x, y in pts])

    def _hits(self, placed: list[tuple[Point, ...]], bodies: np.ndarray,
              obstacles: Sequence[dict]) -> list[dict]:
        seen = {o["name"]: (o["x"], o["y"]) for o in obstacles
                if o["x"] is not None and o["y"] is not None}
        centres = [seen.get(o.name, (math.nan, math.nan)) for o in self.scenario.obstacles]
        out = []
        # an unknown robot or circle (NaN) is never within reach, so never a hit
        for c in load_clearances(self.scenario, placed, bodies, centres):
            if c.clearance < -CONTACT_TOL:
                a, b = self._line(c, placed, bodies, centres)
                out.append({"formation": self._names[c.formation], "other": c.other,
                            "clearance": c.clearance, "line": [list(a), list(b)]})
        return out

    def _line(self, c: LoadContact, placed: list[tuple[Point, ...]], bodies: np.ndarray,
              centres: list[Point]) -> tuple[Point, Point]:
        """(point of the load's outline, point of the other) of a hit."""
        poly = placed[c.formation]
        centre = bounding_circle(poly)[0]
        if c.other in self._index:
            o = bodies[self._index[c.other]]
            other: Point = (float(o[0]), float(o[1]))
        elif c.other in self._shapes:
            other = closest_point(self._shapes[c.other], centre)
        elif c.other in self._names:
            other = closest_point(placed[self._names.index(c.other)], centre)
        else:
            other = centres[[o.name for o in self.scenario.obstacles].index(c.other)]
        return outline_point(poly, other), other


def outline_point(poly: Sequence[Point], p: Point) -> Point:
    """The point of the outline of ``poly`` (a polygon, a segment or a point) nearest ``p``,
    ``p`` inside or not."""
    if len(poly) <= 2:
        return closest_point(poly, p)
    edges = [closest_point((poly[k], poly[(k + 1) % len(poly)]), p) for k in range(len(poly))]
    return min(edges, key=lambda q: math.dist(q, p))


def hull_entries(robots: Sequence[dict]) -> list[dict]:
    """Frame ``loads`` without a scenario: each formation's convex hull of its members' body
    centres (a formation of one robot, or of unknown name, has none)."""
    members: dict[str, list[Point]] = {}
    for r in robots:
        if r["x"] is not None and r["y"] is not None and r["formation"] not in ("", "?"):
            members.setdefault(r["formation"], []).append((r["x"], r["y"]))
    out = []
    for name in sorted(members):
        hull = convex_hull(members[name])
        if len(hull) >= 2:
            out.append({"formation": name, "outline": [[x, y] for x, y in hull],
                        "declared": False})
    return out

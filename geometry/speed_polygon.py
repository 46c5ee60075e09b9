"""The speed disk |u| <= r as the regular polygon inscribed in it (the QP's rows are linear).

One vertex lies along the direction the caller rotates the polygon to (the nominal motion), so the
clamped nominal command itself stays feasible. The per-robot speed rows
(:func:`agent.barriers.speed_rows`), the acceleration rows (:mod:`agent.accel_limit`,
:mod:`agent.double_integrator`) and the formation twist's slot-speed rows (:mod:`agent.body`) are
all this polygon.
"""

from __future__ import annotations

import functools
import math

SIDES = 12  # sides of the polygon inscribed in the speed disk


def face(radius: float, sides: int = SIDES) -> float:
    """The distance of each face from the centre: radius cos(pi / sides)."""
    return radius * _polygon(sides)[0]


def rows(radius: float, heading: float, sides: int = SIDES) -> list[tuple[float, float, float]]:
    """|u| <= radius as the polygon's rows (nx, ny, face), meaning nx ux + ny uy <= face, with
    one vertex along ``heading`` (the nominal direction), so the clamped nominal command itself
    stays feasible."""
    inset, ns = _polygon(sides)
    f = radius * inset
    c0, s0 = math.cos(heading), math.sin(heading)
    return [(c0 * c - s0 * s, s0 * c + c0 * s, f) for c, s in ns]


def normals(sides: int = SIDES) -> tuple[tuple[float, float], ...]:
    """Unit face normals of the polygon for heading 0: angles pi/sides + 2 pi k / sides."""
    return _polygon(sides)[1]


@functools.lru_cache(maxsize=8)
def _polygon(sides: int) -> tuple[float, tuple[tuple[float, float], ...]]:
    """cos(pi / sides) (a face's distance from the centre of the unit polygon) and the unit
    face normals for heading 0, computed once per number of sides."""
    return math.cos(math.pi / sides), tuple(
        (math.cos(math.pi / sides + 2.0 * math.pi * k / sides),
         math.sin(math.pi / sides + 2.0 * math.pi * k / sides))
        for k in range(sides)
    )

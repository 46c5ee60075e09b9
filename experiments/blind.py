"""Blind patches for Monte Carlo runs (``formation montecarlo --localisation fused --blind N``).

Each patch is a box of ``world.camera_blind`` (:class:`scenario.world.BlindBox`) PATCH_LENGTH
by PATCH_WIDTH metres, laid along one formation's way from its start to its goal (its long side
along the way), its centre between PATCH_FROM and PATCH_TO of the way: the formation must cross
it. No patch covers a robot's start (a robot that starts unseen waits for its first pose, which
would never come). Drawn from the run's seed: the run's scenario file replays it exactly.
"""

from __future__ import annotations

import math

import numpy as np

PATCH_LENGTH = 3.5  # [m] along the way
PATCH_WIDTH = 2.0  # [m] across it
PATCH_FROM, PATCH_TO = 0.35, 0.65  # where along the way its centre lies
BLIND_STREAM = 2**42  # the generator's stream
DRAWS = 50  # tries for each patch before it is left out


def centroid(points: list[list[float]]) -> tuple[float, float]:
    return (sum(p[0] for p in points) / len(points), sum(p[1] for p in points) / len(points))


def covers(center: tuple[float, float], yaw: float, x: float, y: float) -> bool:
    """Whether the patch at ``center`` turned by ``yaw`` covers the point (x, y), with a body
    radius to spare."""
    dx, dy = x - center[0], y - center[1]
    c, s = math.cos(yaw), math.sin(yaw)
    u, v = c * dx + s * dy, -s * dx + c * dy
    return abs(u) <= 0.5 * PATCH_LENGTH + 0.2 and abs(v) <= 0.5 * PATCH_WIDTH + 0.2


def draw_patches(d: dict, n: int, seed: int) -> list[dict]:
    """``n`` patches for the scenario mapping ``d`` (``world.camera_blind`` entries)."""
    rng = np.random.default_rng((seed, BLIND_STREAM))
    formations = d["formations"]
    starts = [r["start"] for f in formations for r in f["robots"].values()]
    out: list[dict] = []
    for _ in range(n):
        for _try in range(DRAWS):
            f = formations[int(rng.integers(len(formations)))]
            a = centroid([r["start"] for r in f["robots"].values()])
            b = centroid([r["goal"] for r in f["robots"].values()])
            s = float(rng.uniform(PATCH_FROM, PATCH_TO))
            center = (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]))
            yaw = math.atan2(b[1] - a[1], b[0] - a[0])
            if not any(covers(center, yaw, p[0], p[1]) for p in starts):
                out.append({"box": {"center": [round(center[0], 4), round(center[1], 4)],
                                    "size": [PATCH_LENGTH, PATCH_WIDTH],
                                    "yaw": round(yaw, 6)}})
                break
    return out

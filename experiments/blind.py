"""Blind patches for Monte Carlo runs (``formation montecarlo --localisation fused --blind N``).

Each patch is a box of ``world.camera_blind`` (:class:`scenario.world.BlindBox`) PATCH_LENGTH
by PATCH_WIDTH metres, laid along one formation's way from its start to its goal (its long side
along the way), its centre between PATCH_FROM and PATCH_TO of the way: the formation must cross
it. No patch covers a robot's start (a robot that starts unseen waits for its first pose, which
would never come) nor its goal (a robot stopping on blind floor stops where its estimate says,
its drift away from the goal on the truth: a patch is to be crossed). Drawn from the run's
seed: the run's scenario file replays it exactly.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

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
    ends = [r[k] for f in formations for r in f["robots"].values() for k in ("start", "goal")]
    out: list[dict] = []
    for _ in range(n):
        for _try in range(DRAWS):
            f = formations[int(rng.integers(len(formations)))]
            a = centroid([r["start"] for r in f["robots"].values()])
            b = centroid([r["goal"] for r in f["robots"].values()])
            s = float(rng.uniform(PATCH_FROM, PATCH_TO))
            center = (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]))
            yaw = math.atan2(b[1] - a[1], b[0] - a[0])
            if not any(covers(center, yaw, p[0], p[1]) for p in ends):
                out.append({"box": {"center": [round(center[0], 4), round(center[1], 4)],
                                    "size": [PATCH_LENGTH, PATCH_WIDTH],
                                    "yaw": round(yaw, 6)}})
                break
    return out


def nearest_rank(values: Sequence[float], q: float) -> float | None:
    """The nearest-rank ``q`` quantile of ``values`` (None when there are none)."""
    ordered = sorted(values)
    return ordered[max(0, math.ceil(q * len(ordered)) - 1)] if ordered else None


def spread(values: Sequence[float]) -> dict[str, float | None]:
    """``{median, p95, worst}`` (nearest rank; the worst is the largest) of ``values``."""
    return {"median": nearest_rank(values, 0.5), "p95": nearest_rank(values, 0.95),
            "worst": nearest_rank(values, 1.0)}


def time_cost(fused: Sequence[dict], camera: Sequence[dict]) -> dict:
    """The fused runs' times to their goals against the camera-only runs of the same draws
    (``runs.jsonl`` rows, paired by ``seed`` where both drew the same layout): per pair the
    ratio fused / camera and the extra seconds, as :func:`spread`; pairs where either run
    missed a goal are counted apart (``unreached``), draws found in one folder only as
    ``unpaired``."""
    by_seed = {r["seed"]: r for r in camera}
    ratios: list[float] = []
    extra: list[float] = []
    unreached = unpaired = 0
    for r in fused:
        c = by_seed.get(r["seed"])
        if c is None or c.get("layout_seed") != r.get("layout_seed"):
            unpaired += 1
            continue
        a, b = r.get("time_to_goal_s"), c.get("time_to_goal_s")
        if a is None or b is None or b <= 0.0:
            unreached += 1
            continue
        ratios.append(a / b)
        extra.append(a - b)
    return {"pairs": len(ratios), "unreached": unreached, "unpaired": unpaired,
            "ratio": spread(ratios), "extra_s": spread(extra),
            "ratio_best": min(ratios, default=None), "extra_s_best": min(extra, default=None)}


def read_runs(folder: Path) -> list[dict]:
    """The ``runs.jsonl`` rows of a ``formation montecarlo`` folder."""
    lines = (Path(folder) / "runs.jsonl").read_text(encoding="utf-8").splitlines()
    return [json.loads(line) for line in lines if line.strip()]


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.blind",
                                description="time to goal of fused runs with blind patches "
                                            "against camera-only runs of the same draws")
    p.add_argument("fused", type=Path, help="formation montecarlo --localisation fused --blind N folder")
    p.add_argument("camera", type=Path, help="the same draws' camera-only folder (no patches)")
    ns = p.parse_args(argv)
    try:
        fused, camera = read_runs(ns.fused), read_runs(ns.camera)
    except (OSError, ValueError) as exc:
        print(f"python -m experiments.blind: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(time_cost(fused, camera), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Camera detection benchmark: render frames with 8 and 32 robots at known random poses, detect
them with the camera service, report time per frame and position/heading errors.

    python benchmarks/camera_detection.py [--frames N] [--tilt T] [--noise SIGMA]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camera_service import CameraConfig, CameraService, render_aruco_frame, synthetic_camera  # noqa: E402

ARENA = (-1.0, -1.0, 5.0, 3.5)  # [m]


def poses_for(rng: np.random.Generator, n: int) -> dict[str, tuple[float, float, float]]:
    out: dict[str, tuple[float, float, float]] = {}
    while len(out) < n:
        p = (rng.uniform(ARENA[0] + 0.15, ARENA[2] - 0.15), rng.uniform(ARENA[1] + 0.15, ARENA[3] - 0.15),
             rng.uniform(-math.pi, math.pi))
        if all(math.dist(p[:2], q[:2]) > 0.25 for q in out.values()):
            out[f"r{len(out)}"] = p
    return out


def run(n: int, frames: int, tilt: float, noise: float) -> dict:
    cal = synthetic_camera(arena=ARENA, tilt=tilt)
    rng = np.random.default_rng(n)
    times, pos, head, missed = [], [], [], 0
    for _ in range(frames):
        poses = poses_for(rng, n)
        ids = {r: k for k, r in enumerate(poses)}
        blur = 0.6 if noise else 0.0
        frame = render_aruco_frame(poses, cal, ids, noise_std=noise, blur_sigma=blur, rng=rng)
        service = CameraService(CameraConfig(cal, marker_ids=ids))
        t0 = time.perf_counter()
        seen = {o.robot_id: o for o in service.process(frame, 0.0)}
        times.append((time.perf_counter() - t0) * 1e3)
        missed += n - len(seen)
        for r, (x, y, th) in poses.items():
            if r in seen:
                pos.append(math.dist((x, y), (seen[r].x, seen[r].y)) * 1e3)
                head.append(math.degrees(abs(math.remainder(seen[r].theta - th, 2 * math.pi))))
    return {
        "robots": n, "frames": frames, "missed": missed,
        "ms_median": statistics.median(times), "ms_p99": sorted(times)[int(0.99 * (len(times) - 1))],
        "pos_mm_median": statistics.median(pos), "pos_mm_max": max(pos),
        "head_deg_median": statistics.median(head), "head_deg_max": max(head),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--tilt", type=float, default=0.2)
    ap.add_argument("--noise", type=float, default=2.0)
    ns = ap.parse_args()
    print(f"1280x960 frames, arena {ARENA} m, tilt {ns.tilt}, noise sigma {ns.noise}, 8 cm markers")
    print(f"{'robots':>6} {'frames':>6} {'missed':>6} {'ms med':>7} {'ms p99':>7} {'pos mm med':>10} "
          f"{'pos mm max':>10} {'deg med':>8} {'deg max':>8}")
    for n in (8, 32):
        r = run(n, ns.frames, ns.tilt, ns.noise)
        print(f"{r['robots']:>6} {r['frames']:>6} {r['missed']:>6} {r['ms_median']:>7.1f} "
              f"{r['ms_p99']:>7.1f} "
              f"{r['pos_mm_median']:>10.2f} {r['pos_mm_max']:>10.2f} {r['head_deg_median']:>8.2f} "
              f"{r['head_deg_max']:>8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

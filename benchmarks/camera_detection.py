"""Camera detection benchmark: frames rendered with 8 and 32 robots at known random poses (headings
over the full circle), detected by the camera service; time per frame and pose errors.

    python3 benchmarks/camera_detection.py [--frames N] [--tilt T] [--noise SIGMA] [--blur PX]

One warm-up frame per row, then N timed frames; ``CameraService.process`` is timed (detection
plus the homography mapping), not the rendering. Wall time is what a caller waits; CPU time
(``time.process_time``, all of this process's threads, OpenCV's workers included) is less
disturbed by other load on a shared machine.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camera_service import (
    CameraConfig,
    CameraService,
    default_hues,
    render_aruco_frame,
    render_blob_frame,
    synthetic_camera,
)

ARENA = (0.0, 0.0, 4.0, 3.0)  # [m] floor seen by the 1280x960 synthetic camera
MARKER_SIDE = 0.08  # [m]
INSET = 0.08  # [m] robot centre to arena edge: the marker's quiet zone stays in view
SEPARATION = 0.25  # [m] between robot centres (bodies of radius 0.105 m do not overlap)


def random_poses(rng: np.random.Generator, n: int) -> dict[str, tuple[float, float, float]]:
    poses: dict[str, tuple[float, float, float]] = {}
    while len(poses) < n:
        p = (
            rng.uniform(ARENA[0] + INSET, ARENA[2] - INSET),
            rng.uniform(ARENA[1] + INSET, ARENA[3] - INSET),
            rng.uniform(-math.pi, math.pi),
        )
        if all(math.dist(p[:2], q[:2]) > SEPARATION for q in poses.values()):
            poses[f"r{len(poses):02d}"] = p
    return poses


def run(mode: str, n: int, frames: int, tilt: float, noise: float, blur: float, seed: int) -> dict:
    cal = synthetic_camera(arena=ARENA, tilt=tilt)
    rng = np.random.default_rng(seed + n)
    robots = [f"r{k:02d}" for k in range(n)]
    if mode == "aruco":
        ids = {r: k for k, r in enumerate(robots)}
        config = CameraConfig(cal, marker_ids=ids)

        def render(poses):
            return render_aruco_frame(poses, cal, ids, marker_side=MARKER_SIDE, noise_std=noise,
                                      blur_sigma=blur, rng=rng)
    else:
        hues = default_hues(robots)
        config = CameraConfig(cal, hues=hues, mode="blobs")

        def render(poses):
            return render_blob_frame(poses, cal, hues, noise_std=noise, blur_sigma=blur, rng=rng)

    service = CameraService(config)
    service.process(render(random_poses(rng, n)), 0.0)  # warm-up
    wall, cpu, pos, head, missed = [], [], [], [], 0
    for k in range(frames):
        poses = random_poses(rng, n)
        frame = render(poses)
        t0, c0 = time.perf_counter(), time.process_time()
        seen = {o.robot_id: o for o in service.process(frame, float(k))}
        cpu.append((time.process_time() - c0) * 1e3)
        wall.append((time.perf_counter() - t0) * 1e3)
        missed += n - len(seen)
        for r, (x, y, th) in poses.items():
            if r in seen:
                pos.append(math.dist((x, y), (seen[r].x, seen[r].y)) * 1e3)
                if mode == "aruco":
                    head.append(math.degrees(abs(math.remainder(seen[r].theta - th, 2 * math.pi))))
    return {
        "mode": mode,
        "robots": n,
        "frames": frames,
        "missed": missed,
        "ms_median": float(np.median(wall)),
        "ms_p99": float(np.percentile(wall, 99)),
        "cpu_ms_median": float(np.median(cpu)),
        "pos_mm_median": float(np.median(pos)),
        "pos_mm_max": float(np.max(pos)),
        "head_deg_median": float(np.median(head)) if head else math.nan,
        "head_deg_max": float(np.max(head)) if head else math.nan,
    }


def main(frames: int, tilt: float, noise: float, blur: float, seed: int) -> int:
    load = os.getloadavg()[0]
    print(
        f"1280x960 frames, arena {ARENA} m, marker {MARKER_SIDE} m, tilt {tilt}, noise sigma "
        f"{noise}, blur {blur} px, {frames} frames per row, load average {load:.1f} "
        f"on {os.cpu_count()} cores"
    )
    header = (
        f"{'mode':>6} {'robots':>6} {'frames':>6} {'missed':>6} {'ms med':>7} {'ms p99':>7} "
        f"{'cpu ms':>7} {'pos mm med':>10} {'pos mm max':>10} {'deg med':>8} {'deg max':>8}"
    )
    print(header)
    for mode, n in (("aruco", 8), ("aruco", 32), ("blobs", 8)):
        r = run(mode, n, frames, tilt, noise, blur, seed)
        print(
            f"{r['mode']:>6} {r['robots']:>6} {r['frames']:>6} {r['missed']:>6} "
            f"{r['ms_median']:>7.1f} {r['ms_p99']:>7.1f} {r['cpu_ms_median']:>7.1f} "
            f"{r['pos_mm_median']:>10.2f} {r['pos_mm_max']:>10.2f} "
            f"{r['head_deg_median']:>8.2f} {r['head_deg_max']:>8.2f}"
        )
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100, help="timed frames per row")
    ap.add_argument("--tilt", type=float, default=0.2, help="perspective tilt of the camera")
    ap.add_argument("--noise", type=float, default=3.0, help="sensor noise sigma [grey levels]")
    ap.add_argument("--blur", type=float, default=0.8, help="optical blur sigma [px]")
    ap.add_argument("--seed", type=int, default=1)
    ns = ap.parse_args()
    if ns.frames < 1:
        ap.error("--frames: must be at least 1")
    sys.exit(main(ns.frames, ns.tilt, ns.noise, ns.blur, ns.seed))

"""A rendered overhead frame of the floor markers of ``FLOOR.yaml``, to try ``formation
calibrate`` before a camera is mounted (docs/camera.md, "A first calibration")::

    python -m camera_service.floorframe FLOOR.yaml --out floor.png [--tilt 0.1]

The frame comes from :func:`camera_service.render.render_aruco_frame` through a plausible
overhead camera (:func:`camera_service.calibration.synthetic_camera`) that sees the markers'
bounding box with a margin; the true calibration is written beside it (``--truth``) to compare.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import cv2

from camera_service.calibration import save_calibration, synthetic_camera
from camera_service.config import load_floor
from camera_service.render import MarkerPrint, render_aruco_frame

MARGIN_M = 0.5  # [m] floor seen beyond the outermost markers


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m camera_service.floorframe", description=__doc__)
    p.add_argument("floor", help="FLOOR.yaml: the floor markers' dictionary, size and centres")
    p.add_argument("--out", required=True, help="the frame to write (PNG)")
    p.add_argument("--truth", default=None, help="also write the camera's true calibration here")
    p.add_argument("--tilt", type=float, default=0.1, help="perspective, 0 (straight down) to 0.5")
    ns = p.parse_args(argv)
    try:
        floor = load_floor(ns.floor)
        xs = [c[0] for c in floor.markers.values()]
        ys = [c[1] for c in floor.markers.values()]
        camera = synthetic_camera(arena=(min(xs) - MARGIN_M, min(ys) - MARGIN_M,
                                         max(xs) + MARGIN_M, max(ys) + MARGIN_M), tilt=ns.tilt)
        poses = {f"m{k}": (x, y, 0.0) for k, (x, y) in floor.markers.items()}
        frame = render_aruco_frame(poses, camera, {f"m{k}": k for k in floor.markers},
                                   printed=MarkerPrint(floor.dictionary), marker_side=floor.size_m,
                                   robot_radius=0.0)
    except (OSError, ValueError) as exc:
        print(f"{p.prog}: {exc}", file=sys.stderr)
        return 2
    if not cv2.imwrite(ns.out, frame):
        print(f"{p.prog}: {ns.out}: cannot write the frame", file=sys.stderr)
        return 2
    if ns.truth:
        save_calibration(camera, ns.truth)
    print(f"wrote {ns.out} ({frame.shape[1]}x{frame.shape[0]}, {len(floor.markers)} floor markers)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Calibration and parallax accuracy of the camera service, on the independent
pinhole renderer of the tests (tests/overhead_rig.py, scene of tests/test_camera_process.py).

    python3 benchmarks/camera_accuracy.py FIRST_SEED LAST_SEED [d]

Per seed (a random camera 3 m up, tilted 6 to 12 deg): calibrate from the floor markers with
the true intrinsics and (without ``d``) with the focal length recovered from the homography,
then locate 6 robots' markers 0.19 m up in 6 frames with and without the parallax correction.
``d`` renders a distorted wide-angle lens (intrinsics only). One line per case.
"""
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import numpy as np
import overhead_rig as R
import test_camera_process as T

from camera_service.calibrate import calibrate_image
from camera_service.config import FloorMarkers
from camera_service.locate import Locator

floor = FloorMarkers("DICT_4X4_50", 0.16, T.FLOOR)
for seed in range(int(sys.argv[1]), int(sys.argv[2])):
    rng = np.random.default_rng(seed)
    dist = T.DIST if len(sys.argv) > 3 else None
    rig = R.make_rig(rng, tilt_deg=(6.0, 12.0), dist=dist)
    calimg = T.render(rig, 0.0, rng, robots=False)
    frames = [(k / 15, T.render(rig, k / 15, rng)) for k in range(6)]
    for mode in (["intrinsics"] if dist is not None else ["intrinsics", "homography"]):
        intr = (rig.K, rig.dist if rig.dist is not None else np.zeros(5)) if mode == "intrinsics" else None
        rep = calibrate_image(calimg, floor, intr)
        cpos = np.linalg.norm(np.array(rep.calibration.camera_position) - rig.centre)
        for h in (T.HEIGHT, 0.0):
            loc = Locator(rep.calibration, "DICT_4X4_50", 0.10, h, wanted=list(T.ROBOTS), )
            errs = []
            for t, img in frames:
                f = loc.locate(img)
                for mid, (x, y, _th) in T.robots_at(t).items():
                    if mid in f.poses:
                        errs.append(math.hypot(f.poses[mid][0] - x, f.poses[mid][1] - y))
            med, p95 = np.median(errs) * 1e3, np.percentile(errs, 95) * 1e3
            print(f"seed {seed} {mode:10s} parallax {'on ' if h else 'off'} calib max "
                  f"{rep.max_error_m * 1e3:5.2f} mm  camera pos err {cpos * 1e3:6.1f} mm  "
                  f"robots median {med:6.2f} p95 {p95:6.2f} mm", flush=True)

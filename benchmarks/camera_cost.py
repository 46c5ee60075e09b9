"""CPU cost of one camera frame without Zenoh: JPEG decode to grey and ``Locator.locate`` on
the 16-robot 1280x960 frames of ``formation bench``'s camera section (experiments/camera.py).

    python3 benchmarks/camera_cost.py [FRAMES]

Prints wall medians and the CPU time per frame (``time.process_time``: every thread of this
process), which other people's load on a shared machine disturbs far less than wall time.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import numpy as np

from camera_service.locate import Locator
from experiments.camera import synthetic_frames


def main(frames: int = 60) -> None:
    jpgs, cal, ids = synthetic_frames(16, 15.0)
    loc = Locator(cal, "DICT_4X4_50", 0.10, 0.0, wanted=list(ids.values()))
    dec, det = [], []
    c0 = time.process_time()
    for k in range(frames):
        t0 = time.perf_counter()
        img = cv2.imdecode(np.frombuffer(jpgs[k % len(jpgs)], np.uint8), cv2.IMREAD_GRAYSCALE)
        t1 = time.perf_counter()
        found = loc.locate(img)
        t2 = time.perf_counter()
        assert len(found.poses) == 16
        dec.append((t1 - t0) * 1e3)
        det.append((t2 - t1) * 1e3)
    cpu = (time.process_time() - c0) / frames * 1e3
    print(f"decode median {np.median(dec):.1f} ms, locate median {np.median(det):.1f} ms "
          f"(p99 {np.percentile(det, 99):.1f}), CPU per frame {cpu:.1f} ms, load average "
          f"{os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 60)

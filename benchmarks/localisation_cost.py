"""CPU time of the agent's own filter per tick (``controller.localisation: fused``), for A/B
comparisons: what :class:`agent.odom_in.OdomIn` does with one odometry message, seen and blind.

    PYTHONPATH=TREE python benchmarks/localisation_cost.py [--ticks 20000] [--lag 2] [--json FILE]

One robot drives a straight line at 0.2 m/s at 20 Hz. *seen*: each tick's odometry comes with
a camera pose captured ``--lag`` ticks earlier (a lab camera's latency), fused at its capture
stamp (the filter's update on the stored step, then the later increments predicted again);
*blind*: odometry alone (the prediction). Each is timed with the process's CPU clock over
``--ticks`` ticks, payload decoding and the estimate handed on included; the figures are
microseconds per tick.
"""

from __future__ import annotations

import argparse
import json
import time

from agent.odom_in import OdomIn
from wire.odom import Odom, encode_odom
from wire.payloads import Pose, encode

DT = 0.05
SPEED = 0.2


def run(ticks: int, lag: int, seen: bool) -> float:
    """[us] CPU per tick over ``ticks`` ticks."""
    loc = OdomIn("r1", "warehouse", (0.0, 0.0, 0.0), DT, lockstep=True)
    odoms = [encode_odom(Odom(SPEED * DT if k else 0.0, 0.0, 0.0, max(0, k - 1) * DT, k * DT))
             for k in range(ticks)]
    poses = [encode(Pose(SPEED * DT * max(0, k - lag), 0.0, 0.0, max(0, k - lag) * DT))
             for k in range(ticks)]
    loc.on_camera(poses[0])
    start = time.process_time()
    for k in range(ticks):
        if seen:
            loc.on_camera(poses[k])
        loc.on_odom(odoms[k])
    return (time.process_time() - start) / ticks * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=20000)
    ap.add_argument("--lag", type=int, default=2)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    got = {"seen_us_per_tick": round(run(a.ticks, a.lag, True), 2),
           "blind_us_per_tick": round(run(a.ticks, a.lag, False), 2),
           "ticks": a.ticks, "lag_ticks": a.lag}
    print(json.dumps(got))
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump(got, f, indent=2)


if __name__ == "__main__":
    main()

"""``formation bench --localisation``: the CPU time of the agent's own filter per tick
(``controller.localisation: fused``), what :class:`agent.odom_in.OdomIn` does with one odometry
message, with a camera pose and blind.

One robot drives a straight line at 0.2 m/s at 20 Hz. *seen*: each tick's odometry comes with
a camera pose captured ``lag`` ticks earlier (a lab camera's latency), fused at its capture
stamp (the filter's update on the stored step, then the later increments predicted again);
*blind*: odometry alone (the prediction). Each is timed with the process's CPU clock over
``ticks`` ticks, payload decoding and the estimate handed on included: microseconds per tick.
"""

from __future__ import annotations

import time
from typing import Any

from agent.odom_in import OdomIn
from wire.odom import Odom, encode_odom
from wire.payloads import Pose, encode

DT = 0.05  # [s] the control period
SPEED = 0.2  # [m/s]
TICKS, QUICK_TICKS = 20000, 2000
LAG = 2  # [ticks] from a camera frame's capture to its pose's arrival


def filter_us_per_tick(ticks: int, lag: int, seen: bool) -> float:
    """[us] CPU per tick over ``ticks`` ticks, with a camera pose each tick (``seen``) or
    none."""
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


def bench_localisation(quick: bool = False) -> dict[str, Any]:
    """bench.json of ``formation bench --localisation``."""
    ticks = QUICK_TICKS if quick else TICKS
    return {"localisation": {
        "seen_us_per_tick": round(filter_us_per_tick(ticks, LAG, True), 2),
        "blind_us_per_tick": round(filter_us_per_tick(ticks, LAG, False), 2),
        "ticks": ticks, "lag_ticks": LAG, "period_s": DT}}


def format_localisation(result: dict[str, Any]) -> str:
    """bench.txt: the filter's CPU per tick."""
    r = result["localisation"]
    return (f"agent filter (controller.localisation fused), {r['ticks']} ticks, camera poses "
            f"{r['lag_ticks']} ticks late:\n"
            f"  seen  (predict + late update): {r['seen_us_per_tick']:8.2f} us/tick\n"
            f"  blind (predict):               {r['blind_us_per_tick']:8.2f} us/tick")

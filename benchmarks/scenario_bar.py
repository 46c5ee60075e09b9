"""The scenario bar over every shipped and test scenario, in process, one line per file.

    PYTHONPATH=. python benchmarks/scenario_bar.py [--jobs 2] [--method rigid|thesis] [NAME ...]

The bar: 0 collisions (loads counted), a formation error of at most 1.5 epsilon, every goal
reached, 0 robot-ticks with a hard row unmet and 0 reversals outside ``motion.reversals_forced``
(tests/test_rigid_scenarios.py asserts the same of the rigid set). Each line says ``ok`` or
``FAIL`` and the figures; the last line counts the files that meet it. NAMEs (file stems) pick
files; ``--method`` runs every file under that controller instead of its own. The two closed
rooms of the route set fail it on purpose (their goals have no route: they hold, unreachable).
A whole pass takes about 7 minutes on two quiet cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def measure(job: tuple[Path, str | None]) -> dict:
    from scenario import load_scenario
    from simulator.inprocess import SimOptions, simulate

    path, method = job
    s = load_scenario(path)
    if method is not None:
        s = dataclasses.replace(s, controller=dataclasses.replace(s.controller, method=method))
    began = time.perf_counter()
    summary = simulate(s, SimOptions(record=True)).summary
    motion = summary["motion"]
    row = {"name": path.stem,
           "collisions": summary["collisions"],
           "eps": round(summary["formation_error_max_m"] / s.controller.epsilon, 2),
           "reached": summary["all_reached"],
           "unmet": summary["qp"]["hard_row_unmet_ticks"],
           "reversals": motion["reversals_total"] - motion["reversals_forced_total"],
           "forced": motion["reversals_forced_total"],
           "wall_s": round(time.perf_counter() - began, 1)}
    row["ok"] = (row["collisions"] == 0 and row["eps"] <= 1.5 and row["reached"]
                 and row["unmet"] == 0 and row["reversals"] == 0)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="file stems to run (default: every file)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--method", choices=["rigid", "thesis"], default=None)
    ns = ap.parse_args()
    paths = sorted((ROOT / "scenarios").glob("*.yaml")) + sorted(
        (ROOT / "tests" / "scenarios").glob("*.yaml"))
    if ns.names:
        paths = [p for p in paths if p.stem in set(ns.names)]
    met = 0
    with ProcessPoolExecutor(max(1, ns.jobs)) as pool:
        for row in pool.map(measure, [(p, ns.method) for p in paths]):
            met += row["ok"]
            print(("ok   " if row.pop("ok") else "FAIL ") + json.dumps(row), flush=True)
    print(f"{met} of {len(paths)} files meet the bar")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

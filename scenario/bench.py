"""How long loading a scenario takes as the fleet grows (``formation bench`` reports it;
``python -m scenario.bench`` prints it alone).

A fleet of ``n`` robots is ``n / 4`` rectangles of 0.5 m x 0.25 m in rows of 16, 1.2 m apart
along a row and 0.9 m between rows (close enough that every formation's ellipse has other
robots in its grid cells), written out as a YAML file. Two figures per size, medians of
``repeat`` runs, wall and CPU time of this process: ``validate_ms`` (``validate_cpu_ms``) is
:func:`scenario.load.scenario_from_dict` on the parsed mapping (the checks whose work grows with
the robots), ``load_ms`` (``load_cpu_ms``) is :func:`scenario.load_scenario` on the file (read,
parse, validate).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS

SIZES = (100, 1000)
QUICK_SIZES = (100,)


def fleet_mapping(n: int) -> dict[str, Any]:
    """The scenario mapping of an ``n``-robot fleet (``n`` a multiple of 4, at most 1,024)."""
    if n < 4 or n % 4:
        raise ValueError(f"n: need a positive multiple of 4 robots, got {n}")
    formations = []
    for f in range(n // 4):
        x0, y0 = (f % 16) * 1.2, (f // 16) * 0.9
        ids = [f"f{f}r{i}" for i in range(4)]
        pts = [(x0, y0), (x0 + 0.5, y0), (x0 + 0.5, y0 + 0.25), (x0, y0 + 0.25)]
        formations.append({
            "name": f"f{f}", "leader": ids[1],
            "robots": {r: {"start": [p[0], p[1]], "goal": [p[0] + 40.0, p[1]]}
                       for r, p in zip(ids, pts, strict=True)},
            "edges": [[ids[0], ids[1]], [ids[0], ids[3]], [ids[1], ids[2]], [ids[1], ids[3]],
                      [ids[2], ids[3]]]})
    return {"name": f"fleet-{n}", "dt": 0.05, "duration": 60.0,
            "robot": {"max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS},
            "controller": {"kp": 2.0, "gamma": 1.0, "epsilon": 0.04},
            "formations": formations,
            "obstacles": [{"name": "o1", "center": [-3.0, -3.0], "safe_distance": 0.35}]}


def _median_ms(fn, repeat: int) -> tuple[float, float]:
    """Median wall time and median CPU time of this process [ms] (the CPU time hardly depends
    on other people's load on a shared machine; the wall time does)."""
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def bench_loading(sizes: tuple[int, ...] = SIZES, repeat: int = 5) -> dict[str, Any]:
    """``{"loader": NAME, "sizes": {n: {"bytes", "validate_ms", "validate_cpu_ms", "load_ms",
    "load_cpu_ms"}}}``."""
    from scenario import load_scenario, reader
    from scenario.load import scenario_from_dict

    out: dict[str, Any] = {"loader": reader.LOADER.__name__, "sizes": {}}
    with tempfile.TemporaryDirectory(prefix="bench-scenario-") as tmp:
        for n in sizes:
            mapping = fleet_mapping(n)
            path = Path(tmp) / f"fleet-{n}.yaml"
            path.write_text(yaml.safe_dump(mapping, default_flow_style=None, sort_keys=False),
                            encoding="utf-8")
            validate = _median_ms(lambda m=mapping: scenario_from_dict(m), repeat)
            load = _median_ms(lambda p=path: load_scenario(p), repeat)
            out["sizes"][str(n)] = {"bytes": path.stat().st_size,
                                    "validate_ms": validate[0], "validate_cpu_ms": validate[1],
                                    "load_ms": load[0], "load_cpu_ms": load[1]}
    return out


def format_loading(result: dict[str, Any]) -> str:
    """One line per fleet size."""
    lines = [f"scenario loading ({result['loader']}; medians, wall / CPU ms): validate the "
             "mapping; read + parse + validate the file"]
    for n, r in result["sizes"].items():
        lines.append(f"  {n:>5} robots  {r['bytes'] / 1024:6.1f} kB  validate {r['validate_ms']:7.1f}"
                     f" / {r['validate_cpu_ms']:7.1f}  load {r['load_ms']:7.1f} / "
                     f"{r['load_cpu_ms']:7.1f}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_loading(bench_loading()))

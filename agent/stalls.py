"""What holds an agent host's ticks back, recorded while it runs (``python -m agent.host --stalls
FILE``; ``formation bench --fleets ... --stalls`` gathers every host's): measures a busy machine
does not move much, beside the wall-clock ones.

* the garbage collector's passes per generation: how many, their pause on the wall clock and on
  the collecting thread's CPU clock, on which thread, and how many fell inside a tick;
* the heap: the objects the collector tracks (``len(gc.get_objects())``) and those frozen out of
  its sight (:func:`runtime.heap.freeze_startup`), and the modules loaded;
* every tick of the host's tick thread on the wall clock and on that thread's CPU clock, and the
  longest ones with their parts (:mod:`agent.tick_times`) and the collector's time inside them;
* the CPU time of the host's child processes (the route-plan worker, :mod:`agent.replan`).

Off by default; on, it costs two clock reads per tick and per collection.
"""

from __future__ import annotations

import gc
import heapq
import json
import os
import statistics
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent.tick_times import TICK_PARTS, TickTimes

LONGEST = 10  # the longest ticks kept with their parts
GENERATIONS = (0, 1, 2)


@dataclass
class GcPasses:
    """One generation's collections."""

    wall_ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)
    in_ticks: int = 0  # passes that ran inside a tick
    threads: dict[str, int] = field(default_factory=dict)  # thread name -> passes


class StallProbe:
    """Records the module docstring's figures from :meth:`start` until :meth:`report`."""

    def __init__(self, longest: int = LONGEST) -> None:
        self.longest = longest
        self.gc = {g: GcPasses() for g in GENERATIONS}
        self._gc_start: dict[int, tuple[float, float]] = {}  # thread id -> (wall, cpu) at start
        self._in_tick = False
        self._tick_thread: int | None = None
        self._gc_in_tick_ms = 0.0
        self.tick_wall_ms: list[float] = []
        self.tick_cpu_ms: list[float] = []
        self._top: list[tuple[float, int, dict[str, Any]]] = []  # min-heap of the longest
        self._seen = 0
        self._t0 = time.monotonic()

    def start(self) -> None:
        """From now on (the host's nodes are built: start-up is over)."""
        self._t0 = time.monotonic()
        gc.callbacks.append(self._on_gc)

    def stop(self) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        tid = threading.get_ident()
        if phase == "start":
            self._gc_start[tid] = (time.perf_counter(), time.thread_time())
            return
        began = self._gc_start.pop(tid, None)
        if began is None:
            return
        wall = (time.perf_counter() - began[0]) * 1e3
        passes = self.gc[info.get("generation", 0)]
        passes.wall_ms.append(wall)
        passes.cpu_ms.append((time.thread_time() - began[1]) * 1e3)
        name = threading.current_thread().name
        passes.threads[name] = passes.threads.get(name, 0) + 1
        if self._in_tick and tid == self._tick_thread:
            passes.in_ticks += 1
            self._gc_in_tick_ms += wall

    def tick(self, run: Callable[[], object], robot: str, parts: TickTimes) -> None:
        """Run one tick (``run``) of ``robot`` on this thread and time it; ``parts``: the
        robot's tick times (its ``last`` tick's parts are read for the longest ticks)."""
        self._tick_thread = threading.get_ident()
        self._gc_in_tick_ms = 0.0
        self._in_tick = True
        before = parts.last  # a tick that ends swaps it (agent.tick_times.TickTimes.end)
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        try:
            run()
        finally:
            self._in_tick = False
            wall = (time.perf_counter() - wall0) * 1e3
            cpu = (time.thread_time() - cpu0) * 1e3
            self.tick_wall_ms.append(wall)
            self.tick_cpu_ms.append(cpu)
            self._keep(wall, cpu, robot, parts.last if parts.last is not before else None)

    def _keep(self, wall: float, cpu: float, robot: str, parts: list[int] | None) -> None:
        """Keep the tick if it is among the longest so far; ``parts``: its parts [ns], None
        when no tick ended in it (a pose not due: :func:`agent.schedule.pose_due`)."""
        if len(self._top) >= self.longest and wall <= self._top[0][0]:
            return
        row = {"wall_ms": round(wall, 3), "cpu_ms": round(cpu, 3), "robot": robot,
               "gc_ms": round(self._gc_in_tick_ms, 3),
               "at_s": round(time.monotonic() - self._t0, 3),
               "parts_ms": {name: round(ns * 1e-6, 3)
                            for name, ns in zip(TICK_PARTS, parts or (), strict=False) if ns}}
        self._seen += 1
        entry = (wall, self._seen, row)
        if len(self._top) < self.longest:
            heapq.heappush(self._top, entry)
        else:
            heapq.heapreplace(self._top, entry)

    def report(self) -> dict[str, Any]:
        """The figures so far, JSON-ready."""
        seconds = time.monotonic() - self._t0
        return {
            "seconds": round(seconds, 3),
            "gc": {str(g): gc_figures(p, seconds) for g, p in self.gc.items()},
            "gc_threshold": list(gc.get_threshold()),
            "heap_objects": len(gc.get_objects()),
            "frozen_objects": gc.get_freeze_count(),
            "modules": len(sys.modules),
            "ticks": tick_figures(self.tick_wall_ms, self.tick_cpu_ms),
            "longest_ticks": [row for _, _, row in sorted(self._top, reverse=True)],
            "children_cpu_s": children_cpu_s(),
        }

    def write(self, path: Path) -> None:
        """The report as JSON at ``path`` (written whole, then renamed)."""
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.report(), indent=1) + "\n", encoding="utf-8")
        tmp.replace(path)


def gc_figures(p: GcPasses, seconds: float) -> dict[str, Any]:
    """One generation's passes: count, per minute, pause medians and maxima [ms]."""
    n = len(p.wall_ms)
    return {"passes": n, "per_minute": round(60.0 * n / seconds, 2) if seconds > 0 else None,
            "wall_ms_median": round(statistics.median(p.wall_ms), 3) if n else None,
            "wall_ms_max": round(max(p.wall_ms), 3) if n else None,
            "cpu_ms_median": round(statistics.median(p.cpu_ms), 3) if n else None,
            "cpu_ms_max": round(max(p.cpu_ms), 3) if n else None,
            "in_ticks": p.in_ticks, "threads": dict(p.threads)}


def tick_figures(wall: list[float], cpu: list[float]) -> dict[str, Any]:
    """The ticks' count, CPU median, 99th percentile and maximum, wall maximum [ms]."""
    if not wall:
        return {"count": 0}
    ordered = sorted(cpu)
    return {"count": len(wall), "cpu_ms_median": round(statistics.median(cpu), 4),
            "cpu_ms_p99": round(ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))], 4),
            "cpu_ms_max": round(ordered[-1], 4), "wall_ms_max": round(max(wall), 4)}


def children_cpu_s() -> dict[str, float]:
    """CPU seconds (user + system) of each living child process of this one, by PID (Linux's
    ``/proc``; empty elsewhere)."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tasks:
        try:
            kids = Path(f"/proc/self/task/{tid}/children").read_text(encoding="ascii").split()
        except OSError:
            continue
        for pid in kids:
            try:
                stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii")
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            out[pid] = (int(fields[11]) + int(fields[12])) / tick
    return out

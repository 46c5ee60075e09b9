"""agent.stalls (``python -m agent.host --stalls``) and its summary in ``formation bench``: the
collector's passes by generation, inside ticks or not, the ticks and the longest of them."""

from __future__ import annotations

import gc

from agent.stalls import StallProbe
from agent.tick_times import TICK_PARTS, TickTimes
from experiments.agents import stalls_summary


def test_a_collection_inside_a_tick_is_counted_as_such_and_one_outside_is_not() -> None:
    probe = StallProbe()
    probe.start()
    try:
        times = TickTimes()
        probe.tick(lambda: gc.collect(0), "r1", times)
        gc.collect(0)
    finally:
        probe.stop()
    report = probe.report()
    young = report["gc"]["0"]
    assert young["passes"] >= 2 and young["in_ticks"] == 1
    assert report["ticks"]["count"] == 1
    (longest,) = report["longest_ticks"]
    assert longest["robot"] == "r1" and longest["gc_ms"] > 0.0
    assert report["heap_objects"] > 0 and report["modules"] > 0
    passes = young["passes"]
    gc.collect(0)  # stopped: no longer counted
    assert probe.report()["gc"]["0"]["passes"] == passes


def test_only_the_longest_ticks_are_kept_longest_first_with_their_parts() -> None:
    probe = StallProbe(longest=2)
    times = TickTimes()

    def tick() -> None:
        times.begin()
        sum(range(2000))
        times.lap(TICK_PARTS.index("step"))
        times.end()

    for _ in range(6):
        probe.tick(tick, "r2", times)
    rows = probe.report()["longest_ticks"]
    assert len(rows) == 2
    assert [r["wall_ms"] for r in rows] == sorted((r["wall_ms"] for r in rows), reverse=True)
    assert rows[0]["wall_ms"] == round(max(probe.tick_wall_ms), 3)
    assert set(rows[0]["parts_ms"]) == {"step"}


def _report(young_per_minute: float, in_ticks: int, worst: float, heap: int) -> dict:
    gen = {"per_minute": young_per_minute, "cpu_ms_median": 0.2, "wall_ms_max": worst,
           "in_ticks": in_ticks}
    empty = {"per_minute": 0.0, "cpu_ms_median": None, "wall_ms_max": None, "in_ticks": 0}
    return {"gc": {"0": gen, "1": empty, "2": empty}, "heap_objects": heap,
            "frozen_objects": 40_000, "modules": 400,
            "ticks": {"count": 10, "cpu_ms_p99": 0.5, "wall_ms_max": worst + 1.0},
            "longest_ticks": [{"wall_ms": worst + 1.0, "robot": f"r{heap}"}],
            "children_cpu_s": {"123": 0.25}}


def test_the_bench_sums_the_hosts_reports_up() -> None:
    summary = stalls_summary([_report(10.0, 1, 3.0, 5000), _report(20.0, 2, 5.0, 7000)])
    assert summary["hosts"] == 2
    assert summary["gc"]["0"] == {"per_minute_per_host": 15.0, "cpu_ms_median": 0.2,
                                  "wall_ms_max": 5.0, "in_ticks": 3}
    assert summary["gc"]["2"]["wall_ms_max"] is None
    assert summary["heap_objects"] == 6000
    assert summary["tick_wall_ms_max"] == 6.0
    assert [r["robot"] for r in summary["longest_ticks"]] == ["r7000", "r5000"]
    assert summary["plan_worker_cpu_s"] == 0.5

"""``formation bench --quick``: the smoke mode CI runs. Checks the structure of ``bench.json``
(every key present, every number finite), never timings: benchmarks are not timed tests."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pytest

from agent.control import build_rows
from experiments.bench import bench_step_models
from formation.bench import bench_command, central_problem, fleet_scenario, fleet_snapshot

AGENT_KEYS = ("rate_hz", "world_rate_hz", "missed_ticks", "agent_overruns", "latency_ms_p50",
              "latency_ms_p99", "cpu_percent_per_agent_median", "rss_mb_per_agent_median",
              "latency_parts_ms_median", "load_avg_1min", "fleet_cpu_percent", "early_poses",
              "superseded_poses")


def _finite_numbers(obj, path: str = "") -> list[str]:
    """Paths of every non-finite number in a JSON value."""
    bad = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            bad += _finite_numbers(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            bad += _finite_numbers(v, f"{path}[{i}]")
    elif isinstance(obj, float) and not math.isfinite(obj):
        bad.append(path)
    return bad


@pytest.fixture(scope="module")
def quick_result(tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("bench")
    assert bench_command(argparse.Namespace(out=str(out), quick=True)) == 0
    return json.loads((out / "bench.json").read_text(encoding="utf-8")), out


@pytest.mark.integration
def test_quick_bench_writes_json_and_table(quick_result):
    result, out = quick_result
    assert (out / "bench.txt").read_text(encoding="utf-8").strip()
    assert result["machine"]["quick"] is True
    for key in ("step_us_median", "step", "solvers", "central", "agents", "inprocess"):
        assert key in result, key


def test_quick_bench_numbers_are_finite(quick_result):
    result, _ = quick_result
    assert _finite_numbers(result) == []
    assert result["step_us_median"] > 0
    assert "exact" in result["step"]["solve_us_median"]
    assert "exact" in result["solvers"]
    assert set(result["step"]["by_model"]) >= {"single_integrator", "double_integrator"}


def test_the_step_is_timed_for_both_integrators_on_the_same_instance():
    by_model = bench_step_models(20, rounds=2)
    assert by_model["single_integrator"] > 0 and by_model["double_integrator"] > 0
    assert by_model["double_integrator_status"] == "ok"  # the double integrator's QP was solved


def test_quick_bench_has_central_and_per_robot_side_by_side(quick_result):
    result, _ = quick_result
    assert result["central"]
    for entry in result["central"].values():
        assert entry["per_robot_total_us"] > 0
        assert entry["central_build_us"] > 0
        assert entry["solve_us"] and set(entry["total_us"]) == set(entry["solve_us"])
        for v in entry["max_violation"].values():
            assert v is None or v < 1e-4


def test_quick_bench_ran_agent_processes(quick_result):
    result, _ = quick_result
    assert result["agents"]
    for n, entry in result["agents"].items():
        for key in AGENT_KEYS:
            assert entry.get(key) is not None, (n, key)
        assert entry["commands"] > 0
        assert entry["missed_ticks"] >= 0
        by_input = entry["stale_ticks_by_input"]
        assert set(by_input) <= {"pose", "state", "obstacles", "others", "ellipse"}
        assert sum(by_input.values()) == entry["stale_ticks"]
    assert result["inprocess"]["robot_steps_per_s"] > 0


def test_fleet_scenario_rejects_a_robot_count_not_a_multiple_of_four():
    with pytest.raises(ValueError, match="n:"):
        fleet_scenario(6, 0.02, 1.0)


def test_central_problem_holds_every_robot_and_its_rows():
    scenario = fleet_scenario(8, 0.05, 1.0)
    params, inputs, edges = fleet_snapshot(scenario)
    names = [scenario.formation_of(r).name for r in scenario.robot_ids]
    nominal = [(0.2, 0.0)] * len(inputs)
    pm, q, g, h = central_problem(params, inputs, names, edges, nominal)
    assert pm.shape == (16, 16) and q.shape == (16,)
    single = 0
    for r, u in zip(inputs, nominal, strict=True):
        rows = build_rows(params, r.pose[:2], r.pose[2], u, r._replace(neighbours=()))
        single += len(rows.limits) + len(rows.hard) + len(rows.contact)
    # each robot's own rows + 2 formations x 5 edges x 2 bands + 4 x 4 cross-formation pairs
    assert g.shape == (single + 20 + 16, 16)
    assert h.shape == (g.shape[0],)
    assert (h >= 0).all()  # every barrier holds at the start: standing still is feasible


def test_quick_bench_measures_recording_and_a_watched_fleet(quick_result):
    result, out = quick_result
    rec = result["recording"]
    assert set(rec["robot_steps_per_s"]) == {"loop_only", "with_series", "with_mcap"}
    assert all(v > 0 for v in rec["robot_steps_per_s"].values())
    assert rec["mcap_bytes"] > 0 and rec["record_ms_per_tick"] > 0
    (n, watched), = result["agents_viewer"].items()
    assert n in result["agents"] and watched["commands"] > 0
    assert f"{n}v" in (out / "bench.txt").read_text(encoding="utf-8")
def test_quick_bench_ran_the_camera_process_and_accounted_for_every_frame(quick_result):
    result, out = quick_result
    cam = result["camera"]
    assert cam["robots"] == 16 and cam["image"] == [1280, 960]
    # a loaded machine may skip frames (the camera keeps only the newest waiting one): every
    # frame is handled or counted as skipped, and every handled frame found every robot
    assert cam["frames_handled"] >= 1
    assert cam["frames_handled"] + cam["frames_skipped"] == cam["frames"]
    assert cam["detections_min"] == cam["frames_handled"]
    assert 0 < cam["latency_ms_p50"] <= cam["latency_ms_p99"]
    assert "capture -> publish" in (out / "bench.txt").read_text(encoding="utf-8")

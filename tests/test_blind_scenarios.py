"""The localisation's scenarios (tests/scenarios/blind-*.yaml) against their bar beyond
test_simulation's (every goal, no collision, the band within 1.5 epsilon): the filter refuses
the misread and forged poses, the estimate's error stays within its confidence radius's scale,
and on the camera alone a formation stops at the blind patch."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from tests.scenario_runs import summary_of

SCENARIOS = Path(__file__).parent / "scenarios"
FAULTS = ("blind-misread", "blind-forged", "blind-forged-after-patch")


@pytest.mark.slow
@pytest.mark.parametrize("stem", FAULTS)
def test_misread_and_forged_poses_are_refused_and_counted(stem):
    s = summary_of(SCENARIOS / f"{stem}.yaml")
    loc = s["localisation"]
    assert loc["rejected"] > 0
    assert loc["max_error_m"] < 0.1  # the forged 0.5 m never pulled the estimate
    assert s["collisions"] == 0 and s["all_reached"]


@pytest.mark.slow
def test_on_the_camera_alone_the_formation_stops_at_the_patch():
    sc = load_scenario(SCENARIOS / "blind-aisle.yaml")
    camera = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller,
                                                                    localisation="camera"))
    s = simulate(camera, SimOptions(record=False)).summary
    assert not s["all_reached"] and s["collisions"] == 0
    assert "localisation" not in s
    fused = summary_of(SCENARIOS / "blind-aisle.yaml")
    assert fused["all_reached"] and fused["localisation"]["blind_s"] > 10.0


@pytest.mark.slow
def test_a_fused_run_writes_the_estimate_columns(tmp_path):
    from formation.cli import main

    out = tmp_path / "o"
    assert main(["sim", str(SCENARIOS / "blind-aisle.yaml"), "--out", str(out), "--quiet"]) == 0
    header = (out / "robots.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["est_x", "est_y", "sigma_m"]


@pytest.mark.slow
def test_mujoco_wheels_slip_and_the_filter_still_carries_the_formation_across():
    pytest.importorskip("mujoco")
    sc = load_scenario(SCENARIOS / "blind-aisle-unicycle.yaml")
    s = simulate(sc, SimOptions(record=False, engine="mujoco")).summary
    loc = s["localisation"]
    assert s["all_reached"] and s["collisions"] == 0 and s["physics"]["collisions"] == 0
    assert s["formation_error_max_m"] <= 1.5 * sc.controller.epsilon
    # the wheels' slip adds to the odometry's own errors; the radius still holds the error
    assert loc["max_error_m"] <= loc["max_sigma_m"]

"""Per-robot agent configuration: only what that robot needs, and a faithful YAML round trip."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from agent.config import (
    ZenohSettings,
    build_agent_configs,
    config_from_dict,
    config_to_dict,
    load_config,
    save_config,
)
from scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def configs():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.2.yaml")
    return build_agent_configs(scenario, zenoh=ZenohSettings(mode="client", connect=("tcp/127.0.0.1:7447",)))


def test_each_robot_knows_only_its_neighbours_and_the_leader_its_members(configs):
    r1 = configs["r1"]
    assert dict(r1.neighbours) == {"r2": 0.5, "r4": 0.25}
    assert r1.leader is None and r1.leader_id == "r2" and r1.foreign_robots == ()
    r2 = configs["r2"]
    assert r2.is_leader and set(r2.leader.members) == {"r1", "r2", "r3", "r4"}
    assert r2.leader.other_formations == ("F2",) and r2.leader.axes == (0.6, 0.3)
    assert r1.formation_goal == pytest.approx((3.0, 0.0))
    assert r1.stale_after == pytest.approx(5 * 0.05)


def test_configs_round_trip_through_yaml(configs, tmp_path):
    for rid, cfg in configs.items():
        path = tmp_path / f"{rid}.yaml"
        save_config(cfg, path)
        assert load_config(path) == cfg


def test_all_to_all_configs_list_every_foreign_robot():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.1.yaml")
    cfgs = build_agent_configs(scenario, topology="all-to-all")
    assert set(cfgs["a1"].foreign_robots) == {"b1", "b2"}


@pytest.mark.parametrize("change,message", [
    ({"version": 99}, "version: expected 1"),
    ({"extra": 1}, "unknown field 'extra'"),
    ({"period": -0.1}, "period: must be a positive number"),
    ({"topology": "mesh"}, "topology: 'mesh'"),
    ({"base": "tank"}, "base: 'tank'"),
])
def test_invalid_config_is_refused_naming_the_field(configs, change, message):
    d = config_to_dict(configs["r1"])
    d.update(change)
    with pytest.raises(ValueError, match=message):
        config_from_dict(d)


def test_missing_field_is_named(configs, tmp_path):
    d = config_to_dict(configs["r1"])
    del d["goal"]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ValueError, match="missing field 'goal'"):
        load_config(path)


def test_the_stale_limit_follows_a_camera_slower_than_the_control_period(tmp_path):
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.2.yaml")  # dt 0.05 s
    fast = build_agent_configs(scenario)["r1"]
    assert fast.stale_after == pytest.approx(5 * 0.05) and fast.pose_period is None
    cam15 = build_agent_configs(scenario, pose_period=1 / 15, clock_tolerance=0.05)["r1"]
    assert cam15.stale_after == pytest.approx(5 / 15)  # five camera frames, not five ticks
    assert cam15.clock_tolerance == 0.05
    save_config(cam15, tmp_path / "r1.yaml")
    assert load_config(tmp_path / "r1.yaml") == cam15
    from agent.node import AgentNode

    assert AgentNode(cam15).scheduler.pose_period == pytest.approx(1 / 15)
    with pytest.raises(ValueError, match="pose_period"):
        build_agent_configs(scenario, pose_period=0.0)
    d = config_to_dict(cam15)
    d["clock_tolerance"] = -1.0
    with pytest.raises(ValueError, match="clock_tolerance"):
        config_from_dict(d)


def test_a_unicycles_sampling_margin_is_sized_for_the_camera_period_not_the_control_period():
    scenario = load_scenario(ROOT / "tests/scenarios/unicycle-crossing.yaml")
    dt = scenario.dt
    base = build_agent_configs(scenario)
    slow = build_agent_configs(scenario, pose_period=2 * dt)
    rid = scenario.robot_ids[0]
    assert base[rid].control.period == dt
    assert slow[rid].control.period == 2 * dt
    assert slow[rid].control.sampling_margin == pytest.approx(2 * base[rid].control.sampling_margin)
    assert base[rid].control.sampling_margin > 0

"""Per-robot agent configuration: only what that robot needs, and a faithful YAML round trip."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agent.config import (
    ZenohSettings,
    build_agent_configs,
    config_from_dict,
    config_to_dict,
    load_config,
    save_config,
)
from agent.control import PARAM_RANGES, ControlParams
from agent.node import AgentNode
from scenario import limits, load_scenario
from scenario.model import METHODS, Bounds

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
    ({"period": -0.1}, "period: must be positive, got -0.1"),
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


SWITCHES = [f.name for f in dataclasses.fields(ControlParams)
            if f.name not in PARAM_RANGES and f.name not in ("method", "bounds")]


def _inside(r: limits.Range) -> st.SearchStrategy[float]:
    return st.floats(r.lo, r.hi, exclude_min=r.lo_open, allow_nan=False)


def _outside(r: limits.Range) -> st.SearchStrategy[object]:
    return st.one_of(
        st.floats(max_value=r.lo, exclude_max=not r.lo_open, allow_nan=False),
        st.floats(min_value=r.hi, exclude_min=True),
        st.sampled_from([math.nan, math.inf, -math.inf, "fast", True, None, [1.0]]),
    )


VALID_PARAMS = st.fixed_dictionaries({
    **{name: _inside(r) for name, r in PARAM_RANGES.items()},
    **{name: st.booleans() for name in SWITCHES},
    "method": st.sampled_from(METHODS),
    "bounds": st.fixed_dictionaries({k: _inside(r) for k, r in limits.BOUNDS.items()}).map(
        lambda kw: Bounds(**kw)),
}).map(lambda kw: ControlParams(**kw))


@settings(max_examples=60, deadline=None)
@given(params=VALID_PARAMS)
def test_any_valid_control_params_round_trip_through_the_config_file(configs, tmp_path_factory,
                                                                     params):
    cfg = dataclasses.replace(configs["r2"], control=params)
    path = tmp_path_factory.mktemp("cfg") / "r2.yaml"
    save_config(cfg, path)
    assert load_config(path) == cfg


@settings(max_examples=60, deadline=None)
@given(data=st.data(), name=st.sampled_from(sorted(limits.BOUNDS)))
def test_an_out_of_range_bound_is_refused_naming_it(configs, data, name):
    d = config_to_dict(configs["r1"])
    d["control"]["bounds"] = {name: data.draw(_outside(limits.BOUNDS[name]))}
    with pytest.raises(ValueError, match=rf"^control\.bounds\.{name}: "):
        config_from_dict(d)


def test_an_unknown_method_is_refused_naming_it():
    with pytest.raises(ValueError, match="method: must be one of rigid, thesis"):
        ControlParams(method="fastest")


@settings(max_examples=150, deadline=None)
@given(data=st.data(), name=st.sampled_from(sorted(PARAM_RANGES) + SWITCHES))
def test_an_out_of_range_control_field_is_refused_naming_it(configs, data, name):
    bad = (data.draw(_outside(PARAM_RANGES[name])) if name in PARAM_RANGES
           else data.draw(st.sampled_from([1, 0, "yes", None, 0.5])))
    assume(not (name == "max_accel" and bad is None))  # None: no acceleration limit, allowed
    d = config_to_dict(configs["r1"])
    d["control"][name] = bad
    with pytest.raises(ValueError, match=rf"^control\.{name}: "):
        config_from_dict(d)
    with pytest.raises(ValueError, match=rf"^{name}: "):
        ControlParams(**{name: bad})  # checked where it is built, not only in files


@pytest.mark.parametrize("field,value", [("epsilon", -1), ("gamma_formation", math.nan),
                                         ("kp", "fast")])
def test_the_issues_bad_values_are_refused_naming_the_field_and_the_file(configs, tmp_path,
                                                                         field, value):
    d = config_to_dict(configs["r1"])
    d["control"][field] = value
    path = tmp_path / "r1.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ValueError, match=rf"^{path}: control\.{field}: "):
        load_config(path)


def test_a_control_file_may_leave_out_fields_and_gets_the_dataclass_defaults(configs):
    d = config_to_dict(configs["r1"])
    d["control"] = {"kp": 3.0}
    assert config_from_dict(d).control == ControlParams(kp=3.0)


@pytest.mark.parametrize("where,change,message", [
    ("control", {"kappa": 1.0}, "unknown field 'control.kappa'"),
    ("zenoh", {"config_file": "z.json5"}, "unknown field 'zenoh.config_file'"),
    ("leader", {"ref": 1}, "unknown field 'leader.ref'"),
    ("zenoh", {"mode": "hub"}, r"zenoh\.mode: 'hub' is not one of"),
    ("leader", {"axes": [0.6, -0.3]}, r"leader\.axes\[1\]: must be positive"),
    ("leader", {"members": ["r1", "a/b"]}, r"leader\.members\[1\]: 'a/b' is not a valid name"),
    (None, {"goal": [1e9, 0.0]}, r"^goal\[0\]: out of range"),
    (None, {"goal": [1.0]}, r"^goal: must be a list of 2"),
    (None, {"neighbours": [["r2", 0.5], ["r4", 0]]}, r"^neighbours\[1\]\[1\]: must be positive"),
    (None, {"start": [0.0, 0.0, 99.0]}, r"^start\[2\]: out of range"),
    (None, {"robot_id": 7}, "^robot_id: must be a string"),
    (None, {"partners": ["r 3"]}, r"^partners\[0\]: 'r 3' is not a valid name"),
    (None, {"planner": "yes"}, "^planner: must be true or false"),
    (None, {"pose_period": 5.0}, "^pose_period: out of range"),
    (None, {"stale_after": math.inf}, "^stale_after: must be finite"),
    (None, {"goal_tolerance": 0}, "^goal_tolerance: must be positive"),
    (None, {"prefix": "a//b"}, "prefix 'a//b'"),
])
def test_every_part_of_a_robot_file_is_checked(configs, where, change, message):
    d = config_to_dict(configs["r2"])
    (d if where is None else d[where]).update(change)
    with pytest.raises(ValueError, match=message):
        config_from_dict(d)


def test_a_pose_period_outside_the_control_periods_range_is_refused_when_built():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.2.yaml")
    with pytest.raises(ValueError, match="^pose_period: out of range"):
        build_agent_configs(scenario, pose_period=2.0)


def test_the_agent_exits_2_with_one_line_naming_the_file_and_the_field(configs, tmp_path):
    d = config_to_dict(configs["r1"])
    d["control"]["epsilon"] = -1
    path = tmp_path / "r1.yaml"
    path.write_text(yaml.safe_dump(d))
    proc = subprocess.run([sys.executable, "-m", "agent", "--config", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"agent: {path}: control.epsilon: must be positive")


def test_a_fleet_robots_warehouse_round_trips_and_fixed_robots_files_do_not_name_it(configs,
                                                                                   tmp_path):
    life = load_scenario(ROOT / "tests/scenarios/lifelong/stream-mixed-si.yaml").lifelong
    assert life is not None and life.stream is not None
    cfg = dataclasses.replace(next(iter(configs.values())), lifelong=life)
    path = tmp_path / "fleet.yaml"
    save_config(cfg, path)
    back = load_config(path)
    assert back.lifelong == life
    assert back.lifelong.station("out").dwell_s == life.station("out").dwell_s == 10
    assert "lifelong" not in config_to_dict(next(iter(configs.values())))

"""Fault injection in ``formation run`` (docs/faults.md): message loss and delay at the agents'
subscribers, killed and restarted agents and leaders, a camera that loses a robot's marker.

The process-level runs use lock-step with the fault timeouts; they are the issue's bar (thesis
5.2.2 with 20 % loss has no collision) plus one small two-formation scenario per fault."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from agent.faults import FAULT_CLASSES, DelayLine, LinkFaults, lag
from agent.leader_step import inflate
from formation.cli import main
from simulator.faults import (
    CameraDropout,
    FaultPlan,
    Kill,
    parse_camera_dropout,
    parse_kill,
    restart_log_name,
)
from wire.keys import name_problem
from wire.payloads import EllipseMsg

ROOT = Path(__file__).resolve().parent.parent

TWO_FORMATIONS = (ROOT / "tests" / "scenarios" / "two-small.yaml").read_text(encoding="utf-8")


def run(tmp_path: Path, scenario: Path, *options: str) -> dict:
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--quiet", "--no-plots", *options]) == 0
    return json.loads((out / "summary.json").read_text())


@pytest.fixture
def two(tmp_path: Path) -> Path:
    path = tmp_path / "two.yaml"
    path.write_text(TWO_FORMATIONS, encoding="utf-8")
    return path


# --- the pieces, without processes ------------------------------------------------------------

def test_losses_are_a_pure_function_of_seed_receiver_key_and_stamp():
    f = LinkFaults(drop=0.2, seed=7)
    draws = [f.dropped("r1", "warehouse/robot/r2/state", k * 0.05) for k in range(5000)]
    assert draws == [f.dropped("r1", "warehouse/robot/r2/state", k * 0.05) for k in range(5000)]
    assert 0.18 < sum(draws) / len(draws) < 0.22
    other = [LinkFaults(drop=0.2, seed=8).dropped("r1", "warehouse/robot/r2/state", k * 0.05)
             for k in range(5000)]
    assert draws != other
    assert not any(LinkFaults().dropped("r1", "k", float(k)) for k in range(100))


def test_only_inter_robot_classes_are_faulted():
    f = LinkFaults(drop=0.5)
    assert FAULT_CLASSES == ("state", "ellipse", "others")
    assert all(f.applies_to(c) for c in FAULT_CLASSES)
    assert not any(f.applies_to(c) for c in ("pose", "cmd", "obstacles"))
    assert not LinkFaults().applies_to("state")


@pytest.mark.parametrize("kwargs, name", [({"drop": 1.0}, "drop"), ({"drop": -0.1}, "drop"),
                                          ({"delay": math.nan}, "delay"), ({"seed": -1}, "seed")])
def test_invalid_link_faults_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        LinkFaults(**kwargs)


def test_lock_step_delay_is_rounded_up_to_whole_periods_and_released_in_stamp_order():
    assert lag(0.0, 0.05) == 0.0
    assert lag(0.02, 0.05) == pytest.approx(0.05)
    assert lag(0.1, 0.05) == pytest.approx(0.1)
    out: list[str] = []
    line = DelayLine(0.1, lambda key, payload: out.append(payload.decode()))
    line.push("k", b"b", 0.05)
    line.push("k", b"a", 0.0)
    line.advance(0.05)
    assert out == []
    line.advance(0.1)
    assert out == ["a"]
    line.advance(0.15)
    assert out == ["a", "b"]
    line.push("k", b"old", 0.0)  # already due: straight through
    assert out[-1] == "old" and len(line) == 0


def test_a_stale_ellipse_is_inflated_by_the_distance_its_formation_can_have_covered():
    m = EllipseMsg("F2", 1.0, 2.0, 0.3, 0.6, 0.3, 0.1, 0.0, 0.0, 4.0)
    g = inflate(m, 0.22 * 2.0)
    assert (g.a, g.b) == pytest.approx((0.6 + 0.44, 0.3 + 0.44))
    assert (g.cx, g.cy, g.alpha, g.vx, g.stamp) == (m.cx, m.cy, m.alpha, m.vx, m.stamp)


def test_fault_options_parse_and_bad_ones_name_the_option():
    assert parse_kill("r3@5") == Kill("r3", 5.0, None)
    assert parse_kill("s2@5:3.5") == Kill("s2", 5.0, 3.5)
    assert parse_camera_dropout("r1@5:2") == CameraDropout("r1", 5.0, 2.0)
    for bad in ("r3", "@5", "r3@x", "r3@5:nan"):
        with pytest.raises(ValueError, match="kill"):
            FaultPlan(kills=(parse_kill(bad),))
    with pytest.raises(ValueError, match="camera-dropout"):
        parse_camera_dropout("r1@5")
    with pytest.raises(ValueError, match="kill"):
        FaultPlan(kills=(Kill("r1", 1.0, 0.0),))
    with pytest.raises(ValueError, match="unknown robot"):
        FaultPlan(kills=(Kill("zz", 1.0),)).check_robots(["r1"])
    assert not FaultPlan().active


# --- whole runs --------------------------------------------------------------------------------

@pytest.mark.integration
def test_thesis_5_2_2_with_a_fifth_of_the_messages_lost_has_no_collision(tmp_path):
    s = run(tmp_path, ROOT / "scenarios" / "thesis-5.2.2.yaml", "--drop", "0.2")
    f = s["faults"]
    assert s["collisions"] == 0
    assert s["min_clearance_m"]["robot"] > 0
    assert f["drop"] == 0.2 and f["dropped_messages"] > 1000
    assert set(f["dropped"]) == {"state", "ellipse", "others"} and min(f["dropped"].values()) > 0
    # the receivers' counters: a fifth of what they would have received, within noise
    received = s["comm"]["classes"]["state"]["recv"]["messages"]
    assert 0.15 < f["dropped"]["state"] / (received + f["dropped"]["state"]) < 0.25
    assert s["all_reached"] is True
    assert s["formation_error_max_m"] < 3 * 0.035


@pytest.mark.integration
def test_with_added_delay_every_inter_robot_message_is_held_back_and_the_run_still_completes(
        tmp_path, two):
    s = run(tmp_path, two, "--delay-ms", "100")  # lock-step: two whole periods
    classes = s["comm"]["classes"]
    assert s["faults"]["delayed_messages"] == sum(
        classes[c]["recv"]["messages"] for c in ("state", "ellipse", "others")) > 0
    assert s["collisions"] == 0 and s["all_reached"] is True


@pytest.mark.integration
def test_a_killed_and_restarted_agent_rejoins_and_its_robot_stands_still_meanwhile(tmp_path, two):
    s = run(tmp_path, two, "--kill", "a2@2:2")
    f = s["faults"]
    assert s["collisions"] == 0
    assert [e["event"] for e in f["events"]] == ["kill", "restart"]
    # 2 s without an agent: the world applied zero to a2 for (at least) those 40 ticks
    assert 40 <= f["zero_commands_applied"] <= 80
    # its neighbours saw its state go stale and stopped too
    assert f["stale_ticks_by_input"]["state"] > 0
    assert f["stale_ticks_by_robot"]["a1"] > 0 and f["stale_ticks_by_robot"]["a3"] > 0
    assert f["stale_ticks_by_robot"]["b1"] == 0
    # the new incarnation ran (its counters are the ones reported) and the task completes
    assert s["agents"]["ticks"] > 0
    assert s["all_reached"] is True


@pytest.mark.integration
def test_a_camera_dropout_stops_that_robot_and_counts_it(tmp_path, two):
    s = run(tmp_path, two, "--camera-dropout", "a3@3:1")
    f = s["faults"]
    assert s["collisions"] == 0
    assert f["camera_dropped_poses"] == 20
    assert f["stale_ticks_by_input"]["pose"] >= 20  # a3 commanded zero in every blind tick
    # ... and said so: the world hardly ever had to (only if a wait timed out on a loaded machine)
    assert f["zero_commands_applied"] <= 5
    trace = json.loads((tmp_path / "out" / "agents" / "a3.json").read_text())["trace"]
    blind = [row for row in trace if 3.0 - 1e-9 <= row[0] < 4.0 - 1e-9]
    assert len(blind) == 20 and all(row[7] == "stale" and row[3:7] == [0.0] * 4 for row in blind)
    assert s["all_reached"] is True


@pytest.mark.integration
def test_when_a_leader_dies_its_members_stop_and_its_successor_keeps_its_ellipse_coming(
        tmp_path, two):
    s = run(tmp_path, two, "--kill", "b1@2:2")
    f = s["faults"]
    assert s["collisions"] == 0
    assert f["stale_ticks_by_robot"]["b2"] >= 30  # b2 lost its neighbour: stopped
    assert f["leader_takeovers"] == {"b2": 1}  # b2 led the standing B until b1 was back
    b2 = json.loads((tmp_path / "out" / "agents" / "b2.json").read_text())
    assert b2["acting_leader_ticks"] >= 30 and b2["leader"] is False
    # a1 got B's ellipse from b2 at once: at most a few ticks of the inflated stale one
    stats = json.loads((tmp_path / "out" / "agents" / "a1.json").read_text())
    assert stats["inflated"] == f["inflated_ellipse_ticks"] <= 20
    assert f["stale_ticks_by_robot"]["a1"] == 0  # A went on around B
    assert s["all_reached"] is True


@pytest.mark.integration
def test_in_real_time_the_successor_subscribes_to_the_other_leaders_ellipse_when_it_takes_over(
        tmp_path, two):
    # real time polls its ring channels: the successor's late subscription (agent.node
    # _declare_subscriber, after open) must be drained like the others, or A's ellipse never
    # reaches b2 and B's others never go out
    s = run(tmp_path, two, "--realtime", "--kill", "b1@2:2")
    assert s["collisions"] == 0
    assert s["faults"]["leader_takeovers"] == {"b2": 1}
    b2 = json.loads((tmp_path / "out" / "agents" / "b2.json").read_text())
    assert b2["acting_leader_ticks"] >= 20
    assert "warehouse/formation/A/ellipse" in b2["subscriptions"]
    assert b2["received"]["ellipse"] >= 20  # a member subscribes to no ellipse: all since then


def test_a_restarted_agents_log_never_shares_a_name_with_another_robots_agent():
    # robot a1's second agent and robot a1-2's first once wrote the same logs/agent-a1-2.log
    assert restart_log_name("a1", 2) != "agent-a1-2"
    suffix = restart_log_name("a1", 2).removeprefix("agent-")
    assert name_problem(suffix) is not None  # no robot can be named like a restart

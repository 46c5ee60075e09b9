"""Issue 26 on the agent's side and at the edges: the leader's NavPart under method rigid plans
at its first tick, holds and reports ``unreachable`` for a goal in a closed room, publishes
plan version 2 with a heading per route point that members adopt (a replan of the same goal
too); goal and plan payloads stay version 1, byte for byte, without headings; scenario
waypoints may carry a heading and a moving obstacle may stop (``stop_at``); ``formation check``
refuses a goal with no route."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from agent.config import build_agent_configs, config_to_dict, load_config, save_config
from agent.navigation import NavPart
from formation.cli import main
from formation.commands.goal import parse_via
from geometry.ellipse import Ellipse, reference_shape
from scenario import load_scenario
from scenario.reader import ScenarioError
from viewer.record import route_logs
from wire.navigation import GoalMsg, PlanMsg, decode_goal, decode_plan, encode_nav
from wire.shapes import shape_to_msg

SCENARIOS = Path(__file__).parent / "scenarios"


def _leader_tick(name: str, leader: str):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    cfgs = build_agent_configs(s)
    nav = NavPart(cfgs[leader], leader=True)
    nav.update_shapes(tuple(shape_to_msg(sh) for sh in s.shapes))
    f = s.formations[0]
    ref = reference_shape([r.start[:2] for r in f.robots])
    cx = sum(r.start[0] for r in f.robots) / len(f.robots)
    cy = sum(r.start[1] for r in f.robots) / len(f.robots)
    own = Ellipse(cx, cy, ref.alpha0, 0.5, 0.3)
    nav.step(0.0, True, cx, cy, own, ((), ()))
    return nav, cfgs, (cx, cy)


def test_a_leader_with_a_goal_in_a_closed_room_holds_and_says_unreachable():
    nav, _cfgs, (cx, cy) = _leader_tick("route-closed-room", "r1")
    assert nav.navigator is not None and "no way" in nav.navigator.unreachable
    assert nav.follower.holding and nav.follower.route[0] == (cx, cy)
    status = nav.status_now(1.0, (cx, cy))
    assert status.state == "unreachable" and status.reason
    hold = nav.plan_now(nav.navigator, 1.0)
    assert hold.route == ((cx, cy),)  # the members park where the formation is


def test_a_rigid_leader_plans_headings_its_members_adopt_and_a_replan_too():
    nav, cfgs, _c = _leader_tick("route-line-aisle", "l1")
    assert nav.navigator is not None and nav.navigator.unreachable == ""
    plan = nav.plan_now(nav.navigator, 0.0)
    assert plan.headings and len(plan.headings) == len(plan.route)
    wire = decode_plan(encode_nav(plan))
    assert wire == plan and encode_nav(plan)[0] == 2
    member = NavPart(cfgs["l2"], leader=False)
    assert member.follower.adopt(wire) and member.follower.headings == plan.headings
    again = PlanMsg(plan.formation, plan.goal_stamp, plan.cx, plan.cy, plan.heading,
                    plan.route[1:], plan.members, plan.stamp + 1.0, plan.headings[1:])
    assert member.follower.adopt(again) and member.follower.route == plan.route[1:]
    assert not member.follower.adopt(dataclasses.replace(again, stamp=plan.stamp + 2.0))  # same route


def test_goal_and_plan_without_headings_stay_version_1_and_with_them_round_trip():
    g = GoalMsg("F", 1.0, 2.0, None, ((0.0, 0.0), (1.0, 1.0)), 3.0)
    assert encode_nav(g)[0] == 1 and decode_goal(encode_nav(g)) == g
    g2 = GoalMsg("F", 1.0, 2.0, 0.5, ((0.0, 0.0), (1.0, 1.0)), 3.0, (None, 1.5))
    assert encode_nav(g2)[0] == 2 and decode_goal(encode_nav(g2)) == g2
    with pytest.raises(ValueError, match="headings for"):
        GoalMsg("F", 1.0, 2.0, None, ((0.0, 0.0),), 3.0, (1.0, 2.0))
    with pytest.raises(ValueError, match="finite"):
        PlanMsg("F", 0.0, 1.0, 1.0, None, ((1.0, 1.0),), (), 0.0, (float("nan"),))


def test_scenario_waypoint_headings_and_stop_at(tmp_path):
    src = (SCENARIOS / "route-forklift-parks.yaml").read_text()
    s = load_scenario(SCENARIOS / "route-forklift-parks.yaml")
    fork = s.obstacles[0]
    assert fork.stop_at == 10.0 and fork.position(30.0) == fork.position(10.0)
    assert fork.velocity_at(9.9) == (0.0, 0.5) and fork.velocity_at(10.0) == (0.0, 0.0)
    p = tmp_path / "wp.yaml"
    p.write_text(src.replace("    edges:", "    waypoints: [[-3.0, 3.0, 1.57], [3.0, 3.0]]\n    edges:", 1))
    f = load_scenario(p).formations[0]
    assert f.waypoints == ((-3.0, 3.0), (3.0, 3.0)) and f.waypoint_headings == (1.57, None)
    p.write_text(src.replace("stop_at: 10.0, ", "").replace(
        "{name: shelf-n, box", "{name: shelf-n, stop_at: 3.0, box"))
    with pytest.raises(ScenarioError, match="stop_at"):
        load_scenario(p)


def test_formation_check_refuses_a_goal_with_no_route_in_one_line(capsys):
    assert main(["check", str(SCENARIOS / "route-closed-room.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no route to its goal" in err[0]


def test_the_recording_logs_each_route_planned_again():
    logs = route_logs({"replans": [{"t": 13.0, "formation": "R", "why": "things changed", "waypoints": 7},
                                   {"t": 5.0, "formation": "S", "why": "retry", "waypoints": 0}],
                       "unreachable": {"S": "no way for the footprint"}})
    assert logs[0] == (13.0, "info", "routes", "formation R plans again (things changed): 7 waypoints")
    assert logs[1][1] == "warning" and "no way for the footprint" in logs[1][3]
    assert route_logs({}) == []


def test_a_new_goal_for_a_rigid_formation_gets_the_footprints_route_in_the_same_tick():
    nav, _cfgs, (cx, cy) = _leader_tick("route-line-aisle", "l1")
    sent: list[PlanMsg] = []
    nav.put_plan = lambda plan, stamp: sent.append(plan)  # type: ignore[method-assign]
    nav.offer_goal(GoalMsg("L", 5.0, 0.0, None, (), 10.0))
    own = Ellipse(cx, cy, reference_shape([(cx, cy - 0.75), (cx, cy + 0.75)]).alpha0, 0.9, 0.2)
    nav.step(10.0, True, cx, cy, own, ((), ()))
    assert nav.counts.goals == 1 and nav.navigator is not None
    assert nav.follower.headings and nav.follower.route[-1] == (5.0, 0.0)
    assert sent[-1].headings == nav.follower.headings and sent[-1].stamp == sent[0].stamp
    member = NavPart(_cfgs["l2"], leader=False)
    for plan in sent:  # both plans of the tick, in order: the member ends on the footprint's
        member.follower.adopt(plan)
    assert member.follower.route == nav.follower.route


def test_via_takes_an_optional_heading_and_names_a_bad_one():
    assert parse_via("1,2,0.5") == ((1.0, 2.0), 0.5) and parse_via("1,2") == ((1.0, 2.0), None)
    for bad in ("1", "1,2,3,4", "1,x", "1,2,nan"):
        with pytest.raises(ValueError, match="--via"):
            parse_via(bad)


def test_a_route_given_by_hand_is_never_planned_again_and_survives_the_config_file(tmp_path):
    src = (SCENARIOS / "route-forklift-parks.yaml").read_text()
    p = tmp_path / "wp.yaml"
    p.write_text(src.replace("    edges:", "    waypoints: [[0.0, 3.0, 0.5]]\n    edges:", 1))
    cfgs = build_agent_configs(load_scenario(p))
    cfg = cfgs["r1"]
    assert cfg.route_by_hand and cfg.route_headings == (0.5, None)
    save_config(cfg, tmp_path / "r1")
    assert load_config(tmp_path / "r1") == cfg
    nav = NavPart(cfg, leader=True)
    assert nav.routes is not None and nav.routes.replanner.by_hand
    planned = build_agent_configs(load_scenario(SCENARIOS / "route-forklift-parks.yaml"))["r1"]
    assert not planned.route_by_hand and "route_by_hand" not in config_to_dict(planned)


def _wait_until_gone(worker: int) -> None:
    """Until the plan worker ``worker`` has exited; fails if it outlives its agent by 60 s (the
    limit only ends a wait that would never end)."""
    import os
    import time

    deadline = time.monotonic() + 60.0
    while True:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            return
        assert time.monotonic() < deadline, "the plan worker outlived its agent"
        time.sleep(0.1)


PLAN_POOL_CHILD = """
import os, sys, time
from agent.replan import PLAN_NICE, plan_pool
pool = plan_pool()
pool.submit(int).result()
(pid,) = list(pool._processes)
idle = os.sched_getscheduler(pid) == os.SCHED_IDLE
print(pid, os.getpriority(os.PRIO_PROCESS, pid) == PLAN_NICE and idle, flush=True)
time.sleep(600)
"""


def test_the_route_plan_worker_runs_at_the_lowest_priority_and_ends_when_its_agent_is_killed():
    """agent.replan.plan_pool: the worker is at PLAN_NICE under the idle policy (a waking tick
    takes its CPU at once), and a SIGKILLed agent's worker exits
    by itself (it holds its own queue's write end, so no end of file would ever tell it)."""
    import os
    import signal
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", PLAN_POOL_CHILD], stdout=subprocess.PIPE,
                             text=True, env=dict(os.environ))
    try:
        pid_text, lowest = (child.stdout.readline() if child.stdout else "").split()
        worker = int(pid_text)
        assert lowest == "True"
        os.kill(worker, 0)  # alive while its agent is
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(30)
        if child.stdout is not None:
            child.stdout.close()
    _wait_until_gone(worker)


PLAN_POOL_CLOSE_CHILD = """
import os, time
from agent.replan import close_plan_pool, plan_pool
pool = plan_pool()
pool.submit(int).result()
(pid,) = list(pool._processes)
busy = pool.submit(time.sleep, 600)  # a plan that takes the worker as long as a busy CPU would
while not busy.running():
    time.sleep(0.01)
print(pid, flush=True)
close_plan_pool()
"""


def test_a_stopping_agent_does_not_wait_for_its_plan_workers_current_plan():
    """agent.replan.close_plan_pool (agent.__main__ and agent.host call it on the way out):
    the process exits at once although its worker is in the middle of a plan; left to Python's
    exit, the executor waited for the plan (here 600 s) and the agent outlived its SIGTERM."""
    import os
    import subprocess
    import sys

    child = subprocess.run([sys.executable, "-c", PLAN_POOL_CLOSE_CHILD], capture_output=True,
                           text=True, env=dict(os.environ), timeout=120)  # ends only a hang
    assert child.returncode == 0, child.stderr
    worker = int(child.stdout.split()[0])
    _wait_until_gone(worker)

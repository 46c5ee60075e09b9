"""RunConfig: every check of ``formation run``'s options in one place, and the summary built
from the agents' counters read as AgentStats (no process is started here)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from agent.config import build_agent_configs
from agent.stats import AgentStats
from scenario import load_scenario
from simulator.counters import agent_stats, read_agent_stats
from simulator.faults import FaultPlan, Kill, fault_summary
from simulator.fleet import ChildFailed
from simulator.inprocess import Series
from simulator.metrics import SafetyMonitor
from simulator.run_config import RunConfig
from simulator.summary import build_summary, mark_aborted
from simulator.world import WorldResult
from wire import traffic

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = load_scenario(ROOT / "scenarios" / "thesis-6.3.yaml")


def _config(**kw) -> RunConfig:
    return RunConfig(SCENARIO, Path("/nonexistent/out"), **kw)


class _Remote:
    """A placement of r1 elsewhere (only what RunConfig reads of one)."""

    endpoint = "tcp/192.0.2.1:7447"
    robots = frozenset({"r1"})


@pytest.mark.parametrize(("kw", "message"), [
    ({"port": 70000}, "--port: 70000 is not a TCP port"),
    ({"pose_slots": 0}, "--pose-slots: need an integer >= 1, got 0"),
    ({"pose_slots": 2}, "--pose-slots: more than one slot needs --realtime and --camera truth"),
    ({"clock_offset": 0.01}, "--clock-offset-ms: needs --realtime"),
    ({"pose_zones": -1}, "--pose-zones: need an integer >= 0, got -1"),
    ({"agents_per_process": 0}, "--agents-per-process: need an integer >= 1, got 0"),
    ({"agents_per_process": 2, "faults": FaultPlan(kills=(Kill("r1", 1.0),))},
     "--kill: needs one agent per process"),
    ({"shared_session": True}, "shared session: each robot logs in as itself"),
    ({"faults": FaultPlan(kills=(Kill("z9", 1.0),))}, "kill: unknown robot 'z9'"),
    ({"solver": "no-such-solver"}, "no-such-solver"),
    ({"camera": "process"}, "--camera process needs the scenario file"),
    ({"camera": "fisheye"}, "--camera: 'fisheye' is not one of"),
    ({"remote": _Remote(), "port": 7447}, "--port: not with --hosts"),
    ({"remote": _Remote(), "pose_zones": 2}, "--pose-zones: the zone routers listen on loopback"),
    ({"remote": _Remote(), "faults": FaultPlan(kills=(Kill("r1", 1.0),))},
     "--kill: r1 runs on another host"),
])
def test_a_bad_combination_of_options_is_refused_with_one_line_naming_the_option(kw, message):
    with pytest.raises(ValueError) as caught:
        _config(**kw)
    text = str(caught.value)
    assert message in text and "\n" not in text


def test_a_good_configuration_is_frozen_and_a_replaced_one_is_checked_again():
    config = _config(realtime=True, pose_slots=4, clock_offset=0.002, agents_per_process=2,
                     secure=False, shared_session=True, pose_zones=2)
    assert config.out == Path("/nonexistent/out") and not config.fault_run
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.port = 1  # type: ignore[misc]
    with pytest.raises(ValueError, match="--pose-slots"):
        dataclasses.replace(config, realtime=False)


def _result(steps: int = 3) -> WorldResult:
    return WorldResult(steps=steps, sim_time=steps * SCENARIO.dt, monitor=SafetyMonitor(SCENARIO),
                       series=Series(), traffic=traffic.empty_snapshot())


def test_the_summary_adds_up_the_agents_counters_by_attribute_and_a_killed_agent_counts_nothing(
        tmp_path):
    configs = build_agent_configs(SCENARIO)
    written = AgentStats(robot="r1", formation="F1", ticks=5, stale=2, stale_why={"pose": 2},
                         relaxed=1, solves=5, fault_dropped={"state": 3}, fault_delayed=1,
                         min_h={"formation": 0.5, "obstacle": None, "formations": None},
                         traffic=traffic.empty_snapshot(), cpu_s=0.25, wall_s=1.5)
    (tmp_path / "r1.json").write_text(json.dumps(written.to_json_dict()), encoding="utf-8")
    stats = [agent_stats(tmp_path / f"{rid}.json", cfg, running=rid == "r1", lost_ok=False)
             for rid, cfg in configs.items()]
    assert stats[0] == written and all(s.killed for s in stats[1:])
    summary, _ = build_summary(SCENARIO, _result(), stats, "reduced", False, "truth", True)
    agents = summary["agents"]
    assert (agents["ticks"], agents["stale"], agents["stale_why"]) == (5, 2, {"pose": 2})
    assert agents["cpu_s"] == {"r1": 0.25, "r2": None, "r3": None, "r4": None}
    assert agents["wall_s"] == 1.5 and summary["min_h"]["formation"] == 0.5
    assert (summary["qp"]["solves"], summary["qp"]["infeasible"]) == (5, 1)
    faults = fault_summary(FaultPlan(drop=0.1, kills=(Kill("r2", 1.0),)), _result(), stats, [])
    assert faults["dropped"] == {"state": 3} and faults["delayed_messages"] == 1
    assert faults["stale_ticks_by_robot"] == {"r1": 2, "r2": 0, "r3": 0, "r4": 0}


def test_an_aborted_run_names_the_agents_whose_counters_were_lost_and_a_bad_file_fails(tmp_path):
    cfg = build_agent_configs(SCENARIO)["r3"]
    lost = agent_stats(tmp_path / "r3.json", cfg, running=True, lost_ok=True)
    assert lost.counters_lost and not lost.killed
    summary: dict = {}
    mark_aborted(summary, [lost], KeyboardInterrupt())
    assert summary == {"aborted": "interrupted (Ctrl-C)", "aborted_counters_lost": ["r3"]}
    with pytest.raises(ChildFailed, match="r3.json missing or unreadable"):
        agent_stats(tmp_path / "r3.json", cfg, running=True, lost_ok=False)
    (tmp_path / "r3.json").write_text('{"robot": "r3", "formation": "F1", "tickz": 1}')
    with pytest.raises(ChildFailed, match="unknown keys"):
        read_agent_stats(tmp_path / "r3.json")

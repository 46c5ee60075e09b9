"""AgentStats: the counters an agent writes and the launcher reads back, one dataclass."""

from __future__ import annotations

import json

import pytest

from agent.stats import AgentStats


def test_counters_round_trip_through_json_and_host_fields_appear_only_when_set() -> None:
    s = AgentStats(robot="r1", formation="F1", ticks=7, stale_why={"pose": 2},
                   min_h={"formation": 0.1, "obstacle": None, "formations": 2.0}, trace=[[0.05, 1.0]])
    text = json.dumps(s.to_json_dict(), allow_nan=False)
    assert "host_agents" not in text and "killed" not in text
    assert AgentStats.from_json_dict(json.loads(text)) == s
    hosted = AgentStats(robot="r2", formation="F1", host_agents=4, superseded_poses=0)
    assert hosted.to_json_dict()["host_agents"] == 4 and hosted.to_json_dict()["superseded_poses"] == 0


def test_a_file_missing_counters_reads_as_their_defaults_and_an_unknown_key_is_refused() -> None:
    old = AgentStats.from_json_dict({"robot": "r1", "formation": "F1", "ticks": 3})
    assert old.ticks == 3 and old.stale == 0 and old.min_h["obstacle"] is None
    with pytest.raises(ValueError, match="unknown keys"):
        AgentStats.from_json_dict({"robot": "r1", "formation": "F1", "tickz": 3})
    with pytest.raises(ValueError, match="'robot'"):
        AgentStats.from_json_dict({"formation": "F1"})
    with pytest.raises(ValueError, match="JSON object"):
        AgentStats.from_json_dict([])  # type: ignore[arg-type]

"""Where an agent's tick goes (agent.tick_times, the bench's table of it) and the tick path's
shortcuts: the same answers as the long way."""

from __future__ import annotations

import math

import pytest
import zenoh

from agent.inputs import others_view
from agent.stats import AgentStats
from agent.tick_times import COMMAND, INBOX, STEP, TICK_PARTS, TickTimes
from experiments.agents import tick_parts
from experiments.bench import format_tick_parts
from leader.role import msg_to_ellipse
from wire.payloads import (
    Cmd,
    EllipseMsg,
    Others,
    Pose,
    State,
    decode_cmd,
    decode_ellipse,
    decode_pose,
    decode_state,
    encode,
    encode_zbytes,
)
from wire.traffic import CountingPublisher, TrafficCounter


def test_each_part_gets_the_time_since_the_last_lap_and_a_part_not_run_counts_nothing() -> None:
    times = TickTimes()
    for _ in range(3):
        times.begin()
        times.lap(INBOX)
        times.lap(STEP)
        times.skip()  # a wait: no part's
        times.lap(STEP)  # a part lapped twice adds up
        times.end()
    medians = times.medians()
    assert list(medians) == list(TICK_PARTS)
    assert medians["inbox"] is not None and medians["step"] is not None
    assert medians["inbox"] >= 0.0 and medians["step"] >= 0.0
    assert medians["command"] is None and medians["leader"] is None  # never ran
    times.begin()
    times.lap(COMMAND)
    times.end()
    assert times.medians()["command"] is not None


def test_the_agents_tick_parts_are_their_medians_per_part_in_ms_and_the_table_shows_them() -> None:
    stats = [AgentStats("r1", "f", tick_parts_us_median={"inbox": 30.0, "step": 80.0,
                                                         "leader": 60.0}),
             AgentStats("r2", "f", tick_parts_us_median={"inbox": 50.0, "step": 100.0}),
             AgentStats("r3", "f")]  # an agent that times no parts (an older one)
    parts = tick_parts(stats)
    assert parts["inbox"] == pytest.approx(0.04) and parts["step"] == pytest.approx(0.09)
    assert parts["leader"] == pytest.approx(0.06) and parts["route"] is None
    run = {"robots": 32, "rate_hz_target": 50.0, "pose_zones": 4,
           "latency_parts_ms_median": {"tick": 0.2}, "tick_parts_ms_median": parts}
    lines = format_tick_parts([run])
    assert "step" in lines[1] and lines[2].split()[:4] == ["32", "50", "4", "0.200"]
    assert format_tick_parts([{**run, "tick_parts_ms_median": {}}]) == []  # an older tree's run


def test_counters_with_tick_parts_round_trip_through_json() -> None:
    s = AgentStats("r1", "f", tick_parts_us_median={"inbox": 30.0, "leader": None})
    assert AgentStats.from_json_dict(s.to_json_dict()) == s


def test_an_others_view_is_the_conversion_of_its_message_and_made_once_per_message() -> None:
    own = EllipseMsg("f0", 1.0, 2.0, 0.1, 0.6, 0.3, 0.2, 0.0, 0.0, 5.0, ((1.0, 2.0), (1.5, 2.0)))
    other = EllipseMsg("f1", 4.0, 2.0, 0.0, 0.5, 0.3, 0.0, 0.1, 0.0, 5.0)
    msg = Others("f0", 5.0, (other,), own)
    view = others_view(msg)
    assert view == (msg_to_ellipse(own), (("f1", msg_to_ellipse(other)),))
    assert others_view(msg) is view  # the same message: converted once
    twin = Others("f0", 5.0, (other,), own)  # equal, but another message: its own view
    assert others_view(twin) == view and others_view(twin) is not view
    assert others_view(Others("f0", 5.0)) == (None, ())


@pytest.mark.parametrize("msg, decode", [
    (Pose(1.0, -2.0, 0.5, 7.25), decode_pose),
    (State(1.0, 2.0, 0.1, -0.2, 7.25, 0.3), decode_state),
    (Cmd(0.2, 0.1, 0.2, 0.0, 7.25), decode_cmd),
    (Cmd(0.2, 0.1, 0.2, 0.0, 7.25, 0.5, -0.5), decode_cmd),
])
def test_the_messages_of_every_tick_encode_by_their_type_as_they_decode(msg, decode) -> None:
    assert decode(encode(msg)) == msg
    assert encode_zbytes(msg).to_bytes() == encode(msg)


def test_an_ellipse_keeps_plain_points_as_they_are_and_still_checks_the_rest() -> None:
    pts = ((1.0, 2.0), (3.0, 4.0))
    e = EllipseMsg("f0", 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0, pts, (0.1, 0.2))
    assert e.points is pts and e.headings == (0.1, 0.2)
    assert decode_ellipse(encode(e)) == e
    as_lists = EllipseMsg("f0", 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0, [[1, 2], [3, 4]], [0, 1])
    assert as_lists.points == pts and as_lists.headings == (0.0, 1.0)
    with pytest.raises(ValueError, match="finite"):
        EllipseMsg("f0", 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0, ((1.0, math.inf),))
    with pytest.raises(ValueError, match="headings"):
        EllipseMsg("f0", 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0, pts, (0.1, math.nan))


class _Pub:
    key_expr = "warehouse/robot/r1/cmd"

    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload) -> None:
        self.payloads.append(payload)

    def undeclare(self) -> None:
        pass


def test_a_publisher_counts_each_put_on_its_keys_class_and_a_reset_zeroes_it() -> None:
    counter = TrafficCounter("warehouse")
    pub = CountingPublisher(_Pub(), counter)
    pub.put_message(Cmd(0.0, 0.0, 0.0, 0.0, 1.0))
    pub.put(b"abc")
    assert counter.snapshot()["put"]["cmd"] == {"messages": 2, "bytes": 41 + 3}
    counter.reset()
    assert counter.snapshot()["put"]["cmd"] == {"messages": 0, "bytes": 0}
    pub.put(zenoh.ZBytes(b"abcd"))
    assert counter.snapshot()["put"]["cmd"] == {"messages": 1, "bytes": 4}
    with pytest.raises(ValueError, match="side"):
        counter.entry("sideways", "warehouse/robot/r1/cmd")

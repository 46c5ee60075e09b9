"""The simulated world's pose slots (``WorldOptions.pose_slots``): in real time the poses of a
period go out in evenly spaced slots, each slot stepping its own robots first. One real Zenoh
session on loopback plays the agents: it records every pose and answers with commands."""

from __future__ import annotations

import dataclasses
import itertools
import threading
import time
from pathlib import Path

import pytest
import zenoh

from scenario import load_scenario
from simulator.world import World, WorldOptions
from wire import keys, zconf
from wire.payloads import Cmd, decode_pose, encode

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "two-small.yaml"
P = keys.DEFAULT_PREFIX
UX = 0.1  # [m/s] every robot's command


def run_world(session: zenoh.Session, scenario, slots: int):
    """The world in real time with ``slots`` pose slots, run to its end once the agents (this
    session's subscribers) are there; its result."""
    world = World(scenario, session, WorldOptions(realtime=True, pose_slots=slots,
                                                  stop_at_goal=False))
    try:
        world.wait_for_agents(grace=False)
        return world.run()
    finally:
        world.close()


@pytest.mark.parametrize("bad", [
    {"pose_slots": 0}, {"pose_slots": True}, {"pose_slots": 2.0},
    {"pose_slots": 2},  # lock-step publishes whole frames
    {"pose_slots": 2, "realtime": True, "camera": "synthetic"},
])
def test_pose_slots_are_checked(bad: dict) -> None:
    with pytest.raises(ValueError, match="pose_slots"):
        WorldOptions(**bad)


@pytest.mark.integration
def test_slots_spread_each_periods_poses_and_step_each_robot_once_per_period() -> None:
    scenario = load_scenario(SCENARIO)
    steps = 12
    scenario = dataclasses.replace(scenario, duration=steps * scenario.dt)
    ids = scenario.robot_ids
    n, slots = len(ids), 2
    slot_of = {rid: i * slots // n for i, rid in enumerate(ids)}
    poses: dict[str, list[tuple[float, float]]] = {rid: [] for rid in ids}
    lock = threading.Lock()

    def on_pose(sample: zenoh.Sample) -> None:
        rid = str(sample.key_expr).split("/")[-2]
        p = decode_pose(sample.payload.to_bytes())
        with lock:
            poses[rid].append((p.stamp, p.x))

    conf = zconf.make_config("peer", listen=["tcp/127.0.0.1:0"])
    stop = threading.Event()
    with zenoh.open(conf) as session:
        sub = session.declare_subscriber(keys.all_robots_key(P, keys.POSE), on_pose)
        cmd_pubs = {rid: session.declare_publisher(keys.cmd_key(P, rid)) for rid in ids}

        def agents() -> None:  # every robot keeps commanding UX along x
            while not stop.is_set():
                for pub in cmd_pubs.values():
                    pub.put(encode(Cmd(UX, 0.0, UX, 0.0, time.time())))
                time.sleep(0.005)

        feeder = threading.Thread(target=agents)
        feeder.start()
        try:
            result = run_world(session, scenario, slots)
        finally:
            stop.set()
            feeder.join()
            sub.undeclare()
    assert result.steps == steps
    assert all(len(p) == steps for p in poses.values()), {r: len(p) for r, p in poses.items()}
    for k in range(steps):
        first = max(poses[r][k][0] for r in ids if slot_of[r] == 0)
        second = min(poses[r][k][0] for r in ids if slot_of[r] == 1)
        assert first < second  # slot 1 goes out after slot 0 of the same period ...
        if k + 1 < steps:
            nxt = min(poses[r][k + 1][0] for r in ids if slot_of[r] == 0)
            assert max(poses[r][k][0] for r in ids if slot_of[r] == 1) < nxt  # ... and before the next
    dt = scenario.dt
    for rid in ids:  # each period steps every robot once, by its command
        xs = [x for _stamp, x in poses[rid]]
        assert xs[-1] - xs[-2] == pytest.approx(UX * dt, abs=1e-12)
        assert xs[-1] - xs[0] <= UX * dt * (steps - 1) + 1e-12
    rows = result.series.robots
    assert len(rows) == (steps - 1) * n  # one row per robot and stepped period
    assert {row[8] for row in rows[-n:]} == {UX}  # the applied command's ux (ROBOT_COLUMNS)


class FakeClock:
    """``time.monotonic`` and ``time.sleep`` of a clock that only moves when slept on."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_the_worlds_abort_check_is_rate_limited_but_still_made_while_it_waits(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The launcher's check polls every child process: the world calls it at most every
    ABORT_EVERY_S, however many slots a period has, and at least that often while sleeping."""
    from simulator import pacing

    clock = FakeClock()  # sleep() advances it: no wall-clock time in the counts
    monkeypatch.setattr(pacing, "time", clock)
    calls: list[float] = []
    check = pacing.at_most_every(pacing.ABORT_EVERY_S, lambda: calls.append(clock.now))
    for _ in range(100):
        check()
    assert len(calls) == 1
    wake = clock.now + 6 * pacing.ABORT_EVERY_S
    pacing.sleep_until(wake, check)
    assert clock.now >= wake
    assert len(calls) >= 3
    gaps = [b - a for a, b in itertools.pairwise(calls)]
    assert min(gaps) >= pacing.ABORT_EVERY_S
    assert max(gaps) <= 2 * pacing.ABORT_EVERY_S + 1e-9  # still made while it waits


@pytest.mark.integration
def test_in_real_time_every_pose_of_the_last_frame_gets_its_period_for_the_command() -> None:
    # The agents answer each pose 0.3 periods after it (stamped with it). With 4 slots the last
    # slot's poses go out at 0.75 of the last period, so their commands arrive after the loop
    # ends: before the world waited a period for them, they were lost and counted missed.
    scenario = load_scenario(SCENARIO)
    steps, slots = 8, 4
    scenario = dataclasses.replace(scenario, duration=steps * scenario.dt)
    dt, ids = scenario.dt, scenario.robot_ids
    conf = zconf.make_config("peer", listen=["tcp/127.0.0.1:0"])
    timers: list[threading.Timer] = []
    with zenoh.open(conf) as session:
        cmd_pubs = {rid: session.declare_publisher(keys.cmd_key(P, rid)) for rid in ids}

        def on_pose(sample: zenoh.Sample) -> None:
            rid = str(sample.key_expr).split("/")[-2]
            stamp = decode_pose(sample.payload.to_bytes()).stamp
            timer = threading.Timer(0.3 * dt, lambda: cmd_pubs[rid].put(
                encode(Cmd(0.0, 0.0, 0.0, 0.0, stamp))))
            timers.append(timer)
            timer.start()

        sub = session.declare_subscriber(keys.all_robots_key(P, keys.POSE), on_pose)
        try:
            result = run_world(session, scenario, slots)
        finally:
            sub.undeclare()
            for timer in timers:
                timer.join()
    assert result.steps == steps
    assert len(result.latency_ms) == steps * len(ids)  # one command per pose, the last included
    assert max(result.latency_ms) < dt * 1e3


def test_a_ctrl_c_as_the_run_starts_still_leaves_what_was_measured() -> None:
    """CI once saw ``formation run`` exit 130 with no summary.json: its endpoint file (the sign
    that the world runs) was written before the world's run began, and a Ctrl-C in between met
    no result. The endpoint now goes out from inside the run (``started``)."""
    scenario = load_scenario(SCENARIO)
    conf = zconf.make_config("peer", listen=["tcp/127.0.0.1:0"])
    calls = []

    def started() -> None:
        calls.append(1)
        raise KeyboardInterrupt

    with zenoh.open(conf) as session:
        world = World(scenario, session, WorldOptions(realtime=True))
        try:
            with pytest.raises(KeyboardInterrupt):
                world.run(started=started)
        finally:
            world.close()
    assert calls == [1]
    assert world.result is not None and world.result.steps == 0
    assert world.result.series.robots == []  # nothing was stepped

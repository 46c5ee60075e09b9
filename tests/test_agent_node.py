"""The agent process over real Zenoh sessions on loopback (a Python router in a child process,
explicit ``tcp/127.0.0.1:PORT`` endpoints, multicast scouting off).

The agent under test is r1 of thesis scenario 5.2.2: its graph neighbours are r2 and r4, not r3
(whose state it still reads, for the separation rows); its leader is r2 (formation F1). The
test plays the world and the other robots."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, save_config
from agent.node import AgentNode, NodeOptions
from leader.ellipse import Ellipse
from leader.role import ellipse_to_msg
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from wire import keys, zconf
from wire.payloads import Cmd, ObstacleMsg, Obstacles, Others, Pose, State, decode_cmd, encode

pytestmark = pytest.mark.integration  # most tests run an agent over real Zenoh sessions

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "thesis-5.2.2.yaml"
P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc
    assert proc.returncode == 0


@pytest.fixture(scope="module")
def configs(router: RouterProcess):
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    return build_agent_configs(load_scenario(SCENARIO), zenoh=zs)


class Peer:
    """The test's own session: publishes what the world and the other robots would, and
    records the agent's commands."""

    def __init__(self, endpoint: str) -> None:
        conf = zconf.make_config("client", connect=[endpoint], connect_timeout_s=TIMEOUT_S)
        self.session = zenoh.open(conf)
        self.pubs: dict[str, zenoh.Publisher] = {}
        self.cmds: list[Cmd] = []
        self._lock = threading.Lock()
        self.cmd_sub = self.session.declare_subscriber(keys.cmd_key(P, "r1"), self._on_cmd)

    def _on_cmd(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.cmds.append(decode_cmd(sample.payload.to_bytes()))

    def commands(self) -> list[Cmd]:
        with self._lock:
            return list(self.cmds)

    def put(self, key: str, payload: bytes) -> None:
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key)
        self.pubs[key].put(payload)

    def wait_subscribed(self, key: str) -> None:
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key)
        wait_for_matching(self.pubs[key], TIMEOUT_S)

    def feed(self, t: float, states: bool = True) -> None:
        """Everything r1 needs for the tick stamped ``t`` (its pose last)."""
        self.put(keys.obstacles_key(P), encode(Obstacles(t, (ObstacleMsg("o1", 9.0, 9.0, 0, 0, 0.3),))))
        own = ellipse_to_msg("F1", Ellipse(-3.0, 0.0, 0.0, 0.6, 0.3), t)
        other = ellipse_to_msg("F2", Ellipse(3.0, 0.3, 0.0, 0.6, 0.3), t)
        self.put(keys.others_key(P, "F1"), encode(Others("F1", t, (other,), own)))
        if states:
            self.put(keys.state_key(P, "r2"), encode(State(-2.75, 0.125, 0.2, 0.0, t)))
            self.put(keys.state_key(P, "r4"), encode(State(-3.25, -0.125, 0.2, 0.0, t)))
            self.put(keys.state_key(P, "r3"), encode(State(-2.75, -0.125, 0.2, 0.0, t)))
        self.put(keys.pose_key(P, "r1"), encode(Pose(-3.25, 0.125, 0.0, t)))

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def peer(router: RouterProcess) -> Iterator[Peer]:
    p = Peer(router.endpoint)
    yield p
    p.close()


async def eventually(predicate: Callable[[], bool], timeout_s: float = TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not met in time")
        await asyncio.sleep(0.005)


def run_node(cfg, options: NodeOptions, peer: Peer, body: Callable[[AgentNode], Awaitable[None]]):
    """Run an AgentNode on an asyncio loop, wait for its subscriptions, run ``body``, stop it."""

    async def main() -> AgentNode:
        node = AgentNode(cfg, options)
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        try:
            await asyncio.get_running_loop().run_in_executor(
                None, peer.wait_subscribed, keys.pose_key(P, cfg.robot_id))
            await body(node)
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)
        return node

    return asyncio.run(main())


def test_the_agent_subscribes_to_exactly_its_own_pose_its_members_its_leaders_others_and_obstacles(
    configs,
):
    node = AgentNode(configs["r1"])
    assert set(node.subscribed_keys) == {
        keys.pose_key(P, "r1"), keys.state_key(P, "r2"), keys.state_key(P, "r4"),
        keys.state_key(P, "r3"),  # not a graph neighbour: a separation partner
        keys.others_key(P, "F1"), keys.obstacles_key(P),
    }
    assert not any("*" in k for k in node.subscribed_keys)
    own = {keys.pose_key(P, "r2"), keys.obstacles_key(P),
           *(keys.state_key(P, r) for r in ("r1", "r3", "r4"))}
    # lock-step: the other leader's ellipse; real time: every beacon, the ellipses of the
    # formations near enough once their beacons say so (leader.listen)
    leader = AgentNode(configs["r2"], NodeOptions(lockstep=True))
    assert set(leader.subscribed_keys) == own | {keys.ellipse_key(P, "F2")}
    leader = AgentNode(configs["r2"])
    assert set(leader.subscribed_keys) == own | {"warehouse/formation/*/beacon"}


def test_another_formations_robot_state_never_reaches_the_agent_but_a_neighbours_does(configs, peer):
    async def body(node: AgentNode) -> None:
        for _ in range(5):  # stamped at the lock-step clock's start (later ones: the future)
            peer.put(keys.state_key(P, "s1"), encode(State(0.0, 0.0, 0.0, 0.0, 0.0)))
            peer.put(keys.state_key(P, "r2"), encode(State(1.0, 0.0, 0.0, 0.0, 0.0)))
        await eventually(lambda: node.counter.snapshot()["recv"]["state"]["messages"] >= 5)
        await asyncio.sleep(0.2)  # time for any stray s1 sample to arrive

        assert set(node.inbox.values(keys.STATE)) == {keys.state_key(P, "r2")}
        assert node.inbox.counts()["received"][keys.STATE] == 5
        assert node.counter.snapshot()["recv"]["state"]["messages"] == 5

    run_node(configs["r1"], NodeOptions(lockstep=True), peer, body)


def test_fresh_inputs_give_a_command_and_stale_neighbour_states_give_zero_counted_as_stale(
    configs, peer,
):
    cfg = configs["r1"]

    async def body(node: AgentNode) -> None:
        peer.feed(0.0)
        await eventually(lambda: any(c.stamp == 0.0 for c in peer.commands()))
        first = [c for c in peer.commands() if c.stamp == 0.0][-1]
        assert math.hypot(first.ux, first.uy) > 0.05
        assert node.stale == 0
        # frames go on without neighbour states: once those from t=0 are older than
        # stale_after, the command is zero
        k = 0
        while k * cfg.period <= cfg.stale_after + 1e-9:
            k += 1
            t = k * cfg.period
            peer.feed(t, states=False)
            await eventually(lambda t=t: any(c.stamp == t for c in peer.commands()))
        late = [c for c in peer.commands() if c.stamp == t][-1]
        assert (late.v, late.omega, late.ux, late.uy) == (0.0, 0.0, 0.0, 0.0)
        assert node.stale == 1 and node.stale_why == {"state": 1}
        assert node.ticks == k + 1

    run_node(cfg, NodeOptions(lockstep=True, lockstep_timeout=0.3), peer, body)


def test_malformed_and_non_finite_payloads_are_dropped_counted_and_do_not_stop_the_agent(
    configs, peer,
):
    nan_state = struct.pack("<B6d", 2, math.nan, 0.0, 0.0, 0.0, 0.0, 1.0)
    assert len(nan_state) == len(encode(State(0.0, 0.0, 0.0, 0.0, 1.0)))

    async def body(node: AgentNode) -> None:
        peer.put(keys.state_key(P, "r2"), b"\x07garbage")
        peer.put(keys.state_key(P, "r4"), nan_state)
        peer.put(keys.pose_key(P, "r1"), b"")
        peer.put(keys.others_key(P, "F1"), b"\x01\xff\xff\xff\xff\xff\xff\xff\xff\xff\x7f")
        await eventually(lambda: node.stats().dropped.get("others", 0) == 1)
        await eventually(lambda: node.stats().dropped["state"] == 2)
        assert node.stats().dropped["pose"] == 1
        peer.feed(0.0)  # the agent still works
        await eventually(lambda: any(c.stamp == 0.0 for c in peer.commands()))
        assert node.stale == 0

    run_node(configs["r1"], NodeOptions(lockstep=True, lockstep_timeout=0.3), peer, body)


@contextlib.contextmanager
def _agent_process(cfg_path: Path, stats: Path, *extra: str) -> Iterator[subprocess.Popen]:
    """``python -m agent`` for ``cfg_path`` in a session of its own, killed on the way out if
    it is still running."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "agent", "--config", str(cfg_path),
                             "--stats", str(stats), *extra], env=env, start_new_session=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _last_command_is_zero(peer: Peer) -> bool:
    time.sleep(0.2)  # the zero command crosses the router
    last = peer.commands()[-1]
    return (last.v, last.omega, last.ux, last.uy) == (0.0, 0.0, 0.0, 0.0)


def test_sigterm_makes_the_agent_command_zero_close_and_exit_0(configs, peer, tmp_path):
    cfg_path = tmp_path / "r1.yaml"
    save_config(configs["r1"], cfg_path)
    stats = tmp_path / "r1.json"
    with _agent_process(cfg_path, stats) as proc:
        peer.wait_subscribed(keys.pose_key(P, "r1"))
        deadline = time.monotonic() + TIMEOUT_S
        while not any(math.hypot(c.ux, c.uy) > 0.05 for c in peer.commands()):
            assert time.monotonic() < deadline, "no non-zero command in time"
            peer.feed(time.time())
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(TIMEOUT_S) == 0
    assert _last_command_is_zero(peer)
    assert stats.exists()


@pytest.mark.slow
def test_sigterm_while_poses_pour_in_never_hangs_the_agent(configs, peer, tmp_path):
    # the tick runs on Zenoh's own thread (the pose callback): stopping the process while ticks
    # run there, again and again, must always end in a zero command and exit 0
    cfg_path = tmp_path / "r1.yaml"
    save_config(configs["r1"], cfg_path)
    for round_ in range(6):
        stats = tmp_path / f"r1-{round_}.json"
        with _agent_process(cfg_path, stats, "--no-trace") as proc:
            peer.wait_subscribed(keys.pose_key(P, "r1"))
            before = len(peer.commands())
            t_end = time.monotonic() + 0.8 + 0.1 * round_
            deadline = time.monotonic() + TIMEOUT_S  # a loaded machine: pour on until it ticks
            while time.monotonic() < t_end or len(peer.commands()) <= before + 10:
                assert time.monotonic() < deadline, "the agent does not answer the poses"
                peer.feed(time.time())  # 500 Hz of poses stamped now (a tick per 0.75 dt)
                time.sleep(0.002)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(TIMEOUT_S) == 0
        assert json.loads(stats.read_text())["ticks"] > 10
        assert _last_command_is_zero(peer)


class _PoseSample:
    """What the pose callback reads of a ``zenoh.Sample``."""

    kind = zenoh.SampleKind.PUT

    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr = zenoh.KeyExpr(key)
        self.payload = zenoh.ZBytes(payload)


def test_real_time_ticks_go_by_the_pose_stamps_not_by_arrival_times(configs) -> None:
    from agent.schedule import MIN_SPACING_PERIODS, PoseScheduler

    cfg = configs["r1"]
    node = AgentNode(cfg, NodeOptions(trace=False))
    ticked: list[float] = []
    period = cfg.period
    key = keys.pose_key(P, "r1")

    async def tick(_t: float | None) -> None:  # records the pose each tick runs on
        ticked.append(node.inbox.latest(keys.POSE, key)[0].stamp)

    # the node's inbox (inline before open, with the stamp and plausibility checks) and gate
    scheduler = PoseScheduler(tick, node.gate, node.inbox, key, period, period, cfg.stale_after)

    def pose(stamp: float) -> None:
        scheduler.on_sample(_PoseSample(key, encode(Pose(0.0, 0.0, 0.0, stamp))))

    t0 = time.time() - 0.1
    pose(t0)  # the first pose ticks
    pose(t0 + 0.5 * period)  # a faster camera: stored, not ticked
    assert node.inbox.latest(keys.POSE, key)[0].stamp == t0 + 0.5 * period
    pose(t0 + MIN_SPACING_PERIODS * period)  # due again
    pose(t0 + MIN_SPACING_PERIODS * period)  # the same pose twice: once
    pose(t0 - 0.05)  # older than the pose in use: refused, never ticked on
    pose(t0 - 5.0)  # 5 s old (the camera's clock went back, or a replay): stale, refused
    pose(time.time() + 5.0)  # 5 s in the future: refused, and it blocks nothing after it
    pose(t0 + 2 * period)
    assert ticked == [t0, t0 + MIN_SPACING_PERIODS * period, t0 + 2 * period]
    assert node.inbox.stamps.snapshot() == {"pose": {"future": 1, "stale": 1, "older": 1}}
    node.close()  # no session yet: only marks it closing
    pose(time.time())  # after close() no tick runs
    assert len(ticked) == 3


def test_in_real_time_a_silent_camera_ends_in_deadline_ticks_that_command_zero(configs, peer):
    # while poses come no deadline tick runs; when they stop, the agent ticks on its deadline
    # and, once the pose is stale, commands zero: no later than if it looked every period
    from agent.schedule import DEADLINE_PERIODS

    cfg = configs["r1"]
    span = DEADLINE_PERIODS * cfg.period
    seen: dict[str, float] = {}

    async def body(node: AgentNode) -> None:
        peer.feed(time.time())  # declares the publishers (and waits for their match) first
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:  # a pose every 5 ms, well inside the deadline span
            peer.feed(time.time())
            await asyncio.sleep(0.005)
        await eventually(lambda: any(math.hypot(c.ux, c.uy) > 0.05 for c in peer.commands()))
        seen["ticks"], seen["flowing"] = node.ticks, node.scheduler.counts.deadline_ticks
        silent = time.monotonic()
        await eventually(lambda: node.stale_why.get("pose", 0) > 0)
        seen["zero_after"] = time.monotonic() - silent
        seen["deadline"] = node.scheduler.counts.deadline_ticks
        await asyncio.sleep(0.2)  # the zero command crosses the router

    run_node(cfg, NodeOptions(trace=False), peer, body)
    assert seen["ticks"] > 20
    assert seen["flowing"] <= 1  # (a stall of the test's own sender could earn one)
    assert seen["deadline"] > seen["flowing"]
    # the pose goes stale stale_after after it arrived; a deadline tick follows within a span
    assert seen["zero_after"] <= cfg.stale_after + 2 * span + 0.5
    last = peer.commands()[-1]
    assert (last.v, last.omega, last.ux, last.uy) == (0.0, 0.0, 0.0, 0.0)


def test_lock_step_refuses_frames_beyond_its_window_unless_the_world_went_on_without_it(configs):
    cfg = configs["r1"]
    node = AgentNode(cfg, NodeOptions(lockstep=True, lockstep_timeout=0.3, sim_start=4.0))
    key = keys.pose_key(P, "r1")

    def offer(stamp: float) -> bool:  # into the inbox as a subscriber would (inline before open)
        before = node.inbox.counts()["rejected"].get(keys.POSE, 0)
        node.inbox.offer(keys.POSE, key, encode(Pose(-3.25, 0.125, 0.0, stamp)))
        return node.inbox.counts()["rejected"][keys.POSE] == before

    assert not offer(0.0)  # before the time this (restarted) agent joined at: stale
    assert offer(4.0) and offer(4.0 + cfg.period)  # its frame, and the next one
    assert not offer(30.0)  # far ahead of the frame it is on: refused, blocks nothing
    assert offer(4.0 + 2 * cfg.period)
    assert node.inbox.stamps.snapshot()["pose"] == {"future": 1, "stale": 1, "older": 0}
    # it ticked, then nothing for longer than lockstep_timeout: the world stopped waiting for
    # it, so the next frame is taken even though it is beyond the window
    node.clock.begin_frame(4.0 + 2 * cfg.period, time.monotonic() - 1.0)
    assert offer(12.0) and node.inbox.catch_ups == 1


def test_the_decode_memo_shares_equal_payloads_values_and_never_remembers_a_bad_one():
    from agent.inbox import DecodeMemo
    from wire.payloads import DecodeError, decode_state

    calls = []

    def decode(payload):
        calls.append(payload)
        return decode_state(payload)

    memo = DecodeMemo(decode, size=2)
    a, b, c = (encode(State(float(i), 0.0, 0.0, 0.0, 1.0)) for i in range(3))
    assert memo(a) is memo(bytes(a)) and len(calls) == 1  # equal bytes: one decode, one value
    assert memo(a) == decode_state(a)
    for _ in range(2):
        with pytest.raises(DecodeError):
            memo(b"\x01bad")  # decoded (and refused) every time
    memo(b)
    memo(c)  # full at 2: emptied, then c kept
    memo(a)
    assert calls.count(a) == 2
    before = time.monotonic()
    value, received = memo.stamped(a)  # the value and the reception time, in one call
    assert value is memo(a) and calls.count(a) == 2 and before <= received <= time.monotonic()
    with pytest.raises(DecodeError):
        memo.stamped(b"\x01bad")
    assert memo(bytearray(a)) == decode_state(a)  # not bytes: decoded, not remembered

"""Shutdown steps have time limits: a Zenoh undeclare or session close that hangs
(a router that is gone) is logged and left behind, and the agent and the world still close,
the agent's zero command first."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path

from agent.config import build_agent_configs
from agent.node import AgentNode
from agent.transport import Transport
from runtime.shutdown import within
from scenario import load_scenario
from simulator.world import World
from wire.payloads import Cmd

ROOT = Path(__file__).resolve().parent.parent
LIMIT = 0.2
HUNG_S = 60.0  # a guard that fails a hung test only: every step below that hangs is never freed


def finishes(fn: Callable[[], object]) -> None:
    """Run ``fn`` on a daemon thread and fail only if it has not returned after :data:`HUNG_S`
    (a step that waited for its hung Zenoh call would never return); re-raise what it raised."""
    raised: list[BaseException] = []

    def run() -> None:
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            raised.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(HUNG_S)
    assert not t.is_alive(), f"still waiting after {HUNG_S} s: hung"
    if raised:
        raise raised[0]


class Hangs:
    """A publisher, subscriber or session whose undeclare/close never returns (until freed)."""

    def __init__(self, release: threading.Event) -> None:
        self.release = release
        self.put: list = []

    def put_message(self, msg) -> None:
        self.put.append(msg)

    def undeclare(self) -> None:
        self.release.wait()

    def close(self) -> None:
        self.release.wait()


def test_within_waits_at_most_its_limit_and_reports_a_step_that_hangs(caplog):
    release = threading.Event()  # set only after within() has returned: the step never ends
    answers: list[bool] = []
    with caplog.at_level(logging.WARNING):
        finishes(lambda: answers.append(within(LIMIT, "a hung step", release.wait)))
    assert answers == [False]
    assert "a hung step did not finish within" in caplog.text
    release.set()
    assert within(LIMIT, "a quick step", lambda: None) is True


def test_a_step_that_raises_is_logged_and_shutting_down_goes_on(caplog):
    def boom() -> None:
        raise RuntimeError("gone")

    with caplog.at_level(logging.WARNING):
        assert within(LIMIT, "undeclare", boom) is True
    assert "undeclare failed: gone" in caplog.text


def test_the_agent_closes_in_bounded_time_when_every_zenoh_step_hangs_zero_command_first(caplog):
    cfg = build_agent_configs(load_scenario(ROOT / "tests" / "scenarios" / "two-small.yaml"))["a1"]
    node = AgentNode(cfg)
    release = threading.Event()
    cmd_pub, session = Hangs(release), Hangs(release)
    transport = node.transport = Transport(session, node.counter)
    transport.adopt(node.keys.cmd, cmd_pub)
    transport.keep(None, Hangs(release))
    try:
        with caplog.at_level(logging.WARNING):
            finishes(lambda: node.close(step_limit=LIMIT))  # returns though no step ever ends
        assert [(m.v, m.omega) for m in cmd_pub.put] == [(0.0, 0.0)]
        assert node.transport is None and transport.handles() == []
        assert "closing the Zenoh session did not finish" in caplog.text
        node.close(step_limit=LIMIT)  # idempotent
    finally:
        release.set()


def test_the_agent_closes_even_while_a_tick_holds_its_lock():
    cfg = build_agent_configs(load_scenario(ROOT / "tests" / "scenarios" / "two-small.yaml"))["a1"]
    node = AgentNode(cfg)
    node.gate.lock.acquire()  # a tick that never ends
    try:
        finishes(lambda: node.close(step_limit=LIMIT))  # returns though the lock is never freed
        assert node.gate.closing
    finally:
        node.gate.lock.release()


def test_a_tick_that_outlives_closing_sends_nothing_after_the_zero_command():
    """Under a flood of messages a tick held the lock past the closing wait and its command
    followed the zero one, so the robot's last command was to drive on. Here the tick ends the
    moment the zero goes out, while closing still undeclares (hung for LIMIT)."""
    cfg = build_agent_configs(load_scenario(ROOT / "tests" / "scenarios" / "two-small.yaml"))["a1"]
    node = AgentNode(cfg)
    release, zeroed = threading.Event(), threading.Event()
    cmd_pub = Hangs(release)
    cmd_pub.put_message = lambda msg: (cmd_pub.put.append(msg), zeroed.set())  # type: ignore
    transport = node.transport = Transport(Hangs(release), node.counter)
    transport.adopt(node.keys.cmd, cmd_pub)
    transport.keep(None, Hangs(release))
    node.gate.lock.acquire()  # a tick in progress, past the closing wait

    def tick_ends() -> None:
        assert zeroed.wait(HUNG_S)
        node.send_command(Cmd(0.2, 0.1, 0.2, 0.0, 1.0))  # its command
        node.send_command(Cmd(0.0, 0.0, 0.0, 0.0, 1.0))  # a stop may still go out

    tick = threading.Thread(target=tick_ends, daemon=True)
    tick.start()
    try:
        finishes(lambda: node.close(step_limit=LIMIT))
        tick.join(HUNG_S)
    finally:
        node.gate.lock.release()
        release.set()
    assert [(m.v, m.omega) for m in cmd_pub.put][0] == (0.0, 0.0)
    assert all((m.v, m.omega, m.ux, m.uy) == (0.0, 0.0, 0.0, 0.0) for m in cmd_pub.put)
    assert node.out.late_commands == 1
    assert node.emergency_zero()  # already sent: nothing more


def test_the_world_closes_in_bounded_time_when_undeclaring_hangs():
    release = threading.Event()
    world = object.__new__(World)  # only what close() touches
    world.subs = [Hangs(release)]
    world.pose_pubs = [Hangs(release), Hangs(release)]
    world.obs_pub = Hangs(release)
    world.frames = None  # no --camera process frame publisher
    world.odom = None  # no odometry publishers (controller.localisation camera)
    world.loads = world.loads_pub = None  # no fleet: no loads publisher
    try:
        finishes(lambda: world.close(step_limit=LIMIT))  # returns though no undeclare ever ends
        assert world.subs == [] and world.pose_pubs == []
    finally:
        release.set()

"""The world's loads in ``formation run`` (:mod:`simulator.world_loads`): a load appears when its
order is posted, binds to the roster a team's leader reports, moves with the roster's robots from
``carrying`` on and rests at its destination at ``delivered``; ``world/loads`` goes out before
every frame's poses. The pure part is driven by hand; then a real Zenoh session on loopback
plays the robots' agents and the team's leader against the lock-step world."""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from leader import orders as lo
from leader.team import slot_points
from runtime.testing import free_tcp_port, tcp_endpoint
from scenario import load_scenario
from simulator.lifelong import fleet_base
from simulator.world import World, WorldOptions
from simulator.world_loads import WorldLoads
from wire import keys, zconf
from wire.orders import (
    LoadsMsg,
    OrderMsg,
    OrderStatusMsg,
    decode_loads,
    encode_order,
    order_status_key,
)
from wire.payloads import Cmd, decode_pose, encode

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX
ROSTER = ("f1", "f2", "f3", "f4")
ORDER = OrderMsg("o1", "new", type="pallet", source="in-1", to="rack-2", stamp=0.0)
CARRY_TICKS = 20  # the team carries the pallet to rack-2 in this many ticks


def fleet(duration_ticks: int = 40):
    scenario = fleet_base(load_scenario(ROOT / "tests" / "scenarios" / "lifelong-one-pallet.yaml"))
    return dataclasses.replace(scenario, duration=duration_ticks * scenario.dt)


def slots_of(scenario) -> tuple[tuple[float, float], ...]:
    life = scenario.lifelong
    return slot_points(life.station("in-1").pose, life.load_type("pallet").slots)


def status(state: str, roster=ROSTER, stamp: float = 0.0, reason: str = "") -> OrderStatusMsg:
    return OrderStatusMsg("o1", state, 1, roster, roster[0], reason, stamp)


def test_by_hand_a_load_appears_binds_lifts_follows_its_team_and_rests_at_its_destination():
    scenario = fleet()
    dt = scenario.dt
    loads = WorldLoads(scenario)
    state = [r.start for r in scenario.robots]
    loads.post(ORDER, 0.0)
    loads.events(0.0, state)
    msg = loads.message(0.0)
    assert [(e.name, e.state, e.station, e.order) for e in msg.loads] == [("o1", "resting", "in-1", "")]
    loads.take_status(status(lo.ASSIGNED), 0.0, state)
    assert loads.orders["o1"].state == lo.GATHERING and loads.loads["o1"].order == "o1"
    at = slots_of(scenario)
    state = [(x, y, 0.0) for x, y in at]
    loads.after(dt, state, dt, [])
    assert loads.orders["o1"].t_gathered == pytest.approx(dt)
    assert loads.checks.intrusions == 0  # the team stands under its own load
    loads.take_status(status(lo.CARRYING, roster=ROSTER[::-1]), dt, state)  # another roster
    assert loads.refused == 1 and loads.orders["o1"].state == lo.LIFTING
    loads.take_status(status(lo.CARRYING), dt, state)
    state = [(x + 1.0, y - 0.5, 0.0) for x, y in at]
    loads.after(2 * dt, state, dt, [])
    ld = loads.loads["o1"]
    assert (ld.state, ld.station) == ("carried", "")
    assert ld.pose == pytest.approx((-3.0, 1.0, 1.5708))
    loads.take_status(status(lo.DELIVERED), 2 * dt, state)
    assert (ld.state, ld.station, ld.order) == ("resting", "rack-2", "")
    assert loads.orders["o1"].state == lo.DELIVERED and loads.under["f1"] == {"o1"}
    loads.after(3 * dt, state, dt, [])
    assert loads.checks.intrusions == 0  # the robots under it may leave it
    assert loads.finished(more=False) and not loads.finished(more=True)
    assert [r[6] for r in loads.rows] == ["resting", "resting", "carried", "carried", "resting"]


def test_by_hand_a_member_lost_after_the_lift_sets_the_load_down_where_it_stands():
    scenario = fleet()
    loads = WorldLoads(scenario)
    state = [r.start for r in scenario.robots]
    loads.post(ORDER, 0.0)
    loads.events(0.0, state)
    loads.take_status(status(lo.ASSIGNED), 0.0, state)
    state = [(x, y, 0.0) for x, y in slots_of(scenario)]
    loads.take_status(status(lo.CARRYING), 0.1, state)
    state = [(x + 0.5, y, 0.0) for x, y, _ in state]
    loads.after(0.15, state, 0.05, [])
    loads.take_status(status(lo.FAILED, reason="member lost: f3"), 0.15, state)
    ld, order = loads.loads["o1"], loads.orders["o1"]
    assert (ld.state, ld.station, ld.order) == ("resting", "", "")
    assert ld.pose[0] == pytest.approx(-3.5)
    assert (order.state, order.reason) == (lo.FAILED, "member lost: f3")


def test_by_hand_a_new_load_waits_for_a_robot_standing_at_its_source():
    scenario = fleet()
    loads = WorldLoads(scenario)
    src = scenario.lifelong.station("in-1").pose
    state = [r.start for r in scenario.robots]
    state[0] = src
    loads.post(ORDER, 0.0)
    loads.events(0.0, state)
    assert "o1" not in loads.loads and loads.message(0.0).loads == ()
    state[0] = scenario.robots[0].start
    loads.events(0.05, state)
    assert loads.loads["o1"].station == "in-1"


class FakeTeam:
    """One Zenoh session playing every robot's agent and the team's leader in lock-step: for
    each frame (all poses of one stamp) it puts the statuses ``script`` gives, then each robot's
    command; it records every ``world/loads`` it hears."""

    def __init__(self, session: zenoh.Session, ids: tuple[str, ...],
                 script: Callable[[int, dict], tuple[list[OrderStatusMsg], dict]], dt: float):
        self.session, self.ids, self.script, self.dt = session, ids, script, dt
        self.poses: queue.SimpleQueue = queue.SimpleQueue()
        self.loads: list[LoadsMsg] = []
        self.order_seen: list[tuple[float, int]] = []  # (loads stamp, poses heard before it)
        self._heard_poses = 0
        self.stop = threading.Event()
        self.cmd = {r: session.declare_publisher(keys.cmd_key(P, r)) for r in ids}
        # called on the Zenoh thread that received each sample (as the agents' inboxes are), so
        # the samples of one sender are seen in the order they were put
        self.subs = [session.declare_subscriber(keys.all_robots_key(P, keys.POSE),
                                                zenoh.handlers.Callback(self._pose, indirect=False)),
                     session.declare_subscriber(keys.loads_key(P),
                                                zenoh.handlers.Callback(self._loads, indirect=False))]
        self.thread = threading.Thread(target=self._run)
        self.thread.start()

    def _pose(self, sample: zenoh.Sample) -> None:
        self._heard_poses += 1
        self.poses.put((str(sample.key_expr).split("/")[-2], decode_pose(sample.payload.to_bytes())))

    def _loads(self, sample: zenoh.Sample) -> None:
        msg = decode_loads(sample.payload.to_bytes())
        self.order_seen.append((msg.stamp, self._heard_poses))
        self.loads.append(msg)

    def _run(self) -> None:
        frames: dict[float, dict] = {}
        while not self.stop.is_set():
            try:
                rid, pose = self.poses.get(timeout=0.05)
            except queue.Empty:
                continue
            frame = frames.setdefault(pose.stamp, {})
            frame[rid] = (pose.x, pose.y)
            if len(frame) < len(self.ids):
                continue
            k = round(pose.stamp / self.dt)
            statuses, velocities = self.script(k, frames.pop(pose.stamp))
            for msg in statuses:
                self.session.put(order_status_key(P, msg.oid), encode_order(
                    dataclasses.replace(msg, stamp=pose.stamp)))
            for r in self.ids:
                ux, uy = velocities.get(r, (0.0, 0.0))
                self.cmd[r].put(encode(Cmd(math.hypot(ux, uy), 0.0, ux, uy, pose.stamp)))

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        for s in self.subs:
            s.undeclare()


def test_over_zenoh_the_world_moves_the_load_with_the_team_its_leader_reports():
    scenario = fleet()
    dt = scenario.dt
    slots = dict(zip(ROSTER, slots_of(scenario), strict=True))
    life = scenario.lifelong
    src, dst = life.station("in-1").pose, life.station("rack-2").pose
    step = ((dst[0] - src[0]) / (CARRY_TICKS * dt), (dst[1] - src[1]) / (CARRY_TICKS * dt))

    def script(k: int, at: dict) -> tuple[list[OrderStatusMsg], dict]:
        if k == 0:  # the team commits and every member goes to its slot in one tick
            return [status(lo.ASSIGNED)], {r: ((slots[r][0] - at[r][0]) / dt,
                                               (slots[r][1] - at[r][1]) / dt) for r in ROSTER}
        if k == 1:  # a status naming another roster: refused
            return [status(lo.CARRYING, roster=ROSTER[::-1])], {}
        if 2 <= k < 2 + CARRY_TICKS:
            return ([status(lo.CARRYING)] if k == 2 else []), dict.fromkeys(ROSTER, step)
        if k == 2 + CARRY_TICKS:
            return [status(lo.DELIVERED)], {}
        return [], {}

    port = free_tcp_port()
    with zenoh.open(zconf.make_config("peer", listen=[tcp_endpoint(port)])) as world_session, \
            zenoh.open(zconf.make_config("peer", connect=[tcp_endpoint(port)])) as team_session:
        team = FakeTeam(team_session, scenario.robot_ids, script, dt)
        world = World(scenario, world_session, WorldOptions(realtime=False, cmd_timeout=10.0))
        try:
            world.wait_for_agents(grace=False)
            result = world.run(on_tick=lambda k, t: world.post_order(ORDER, t) if k == 0 else None)
        finally:
            world.close()
            team.close()
    loads = world.loads
    assert loads is not None
    order = loads.orders["o1"]
    assert order.state == lo.DELIVERED
    assert (order.t_assigned, order.t_gathered, order.t_lifted, order.t_delivered) == \
        pytest.approx((0.0, dt, 2 * dt, (2 + CARRY_TICKS) * dt))
    assert result.steps == 3 + CARRY_TICKS  # every order done: the run ends
    assert loads.refused == 1 and world.status_dropped == 0
    ld = loads.loads["o1"]
    assert (ld.state, ld.station) == ("resting", "rack-2")
    assert ld.pose[:2] == pytest.approx(dst[:2], abs=1e-9)
    assert loads.checks.events == [] and loads.checks.intrusions == 0
    # world/loads went out every tick, each before that frame's poses
    assert [round(m.stamp / dt) for m in team.loads] == list(range(result.steps))
    assert all(heard == k * len(scenario.robot_ids)
               for k, (_stamp, heard) in enumerate(team.order_seen))
    first, middle = team.loads[0].loads[0], team.loads[2 + CARRY_TICKS // 2].loads[0]
    assert (first.state, first.station, first.order) == ("resting", "in-1", "")
    assert (middle.state, middle.station, middle.order) == ("carried", "", "o1")
    assert middle.x == pytest.approx(src[0] + CARRY_TICKS // 2 * step[0] * dt)
    carried_rows = [r for r in loads.rows if r[6] == "carried"]
    assert len(carried_rows) == 1 + CARRY_TICKS  # at the lift, then one a tick


def test_the_live_watcher_draws_the_worlds_loads_outlined_by_their_types():
    from types import SimpleNamespace

    from scenario.lifelong import outline_at
    from viewer.live import FleetWatcher
    from wire.orders import LoadEntry, encode_loads
    from wire.payloads import Pose, encode

    class Session:
        def declare_subscriber(self, key, handler):
            return SimpleNamespace(undeclare=lambda: None)

    scenario = fleet()
    w = FleetWatcher(Session(), scenario=scenario)

    def put(key: str, data: bytes) -> None:
        w.on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))

    put("warehouse/robot/f1/pose", encode(Pose(0.0, 0.0, 0.0, 2.0)))
    assert "cargo" not in w.frame()
    put("warehouse/world/loads", encode_loads(LoadsMsg(2.0, (
        LoadEntry("o1", "pallet", -3.0, 1.0, 0.5, "carried", "", "o1"),
        LoadEntry("p9", "crate", 0.0, 0.0, 0.0, "resting", "rack-1")))))  # a type it lacks
    (cargo,) = w.frame()["cargo"]
    pallet = scenario.lifelong.load_type("pallet")
    assert (cargo["name"], cargo["state"], cargo["order"]) == ("o1", "carried", "o1")
    assert cargo["outline"] == [[x, y] for x, y in outline_at(pallet, (-3.0, 1.0, 0.5))]
    put("warehouse/world/loads", b"\x01junk")
    assert w.frame()["cargo"][0]["name"] == "o1" and w.rejected == {"loads": 1}


def test_by_hand_a_cancel_ends_a_waiting_order_whose_load_never_appeared():
    scenario = fleet()
    loads = WorldLoads(scenario)
    src = scenario.lifelong.station("in-1").pose
    state = [src] + [r.start for r in scenario.robots[1:]]  # a robot on the source: no room
    loads.post(ORDER, 0.0)
    loads.events(0.0, state)
    loads.take_status(OrderStatusMsg("o1", lo.CANCELLED, reason="cancelled"), 0.05, state)
    assert loads.orders["o1"].state == lo.CANCELLED and loads.finished(more=False)
    loads.events(0.1, [r.start for r in scenario.robots])
    assert "o1" not in loads.loads  # a cancelled order's load never comes


def test_the_launcher_keeps_the_world_in_step_with_the_fleet_managers_book():
    from simulator.launch import sync_order
    from simulator.manager import REFUSED, Entry

    class World:  # what the launcher asks of the world
        def __init__(self) -> None:
            self.heard: list[OrderStatusMsg] = []

        def post_order(self, msg, t, refused=""):
            loads.post(msg, t, refused)

        def hear(self, msg):
            self.heard.append(msg)

    scenario = fleet()
    loads, world = WorldLoads(scenario), World()
    waiting = OrderStatusMsg("o1", lo.WAITING)
    sync_order(world, loads, Entry(ORDER, waiting, 0.0), 0.0)
    bad = OrderMsg("m1", "new", type="crate", source="in-1", to="rack-2")
    sync_order(world, loads, Entry(bad, OrderStatusMsg("m1", lo.FAILED, reason=REFUSED + "type"),
                                   0.0), 0.0)
    assert loads.orders["o1"].state == lo.WAITING
    assert (loads.orders["m1"].state, loads.orders["m1"].reason) == (lo.FAILED, REFUSED + "type")
    sync_order(world, loads, Entry(dataclasses.replace(ORDER, priority=3.0), waiting, 0.0), 0.5)
    assert loads.orders["o1"].priority == 3.0 and world.heard == []
    cancelled = OrderStatusMsg("o1", lo.CANCELLED, reason="cancelled")
    sync_order(world, loads, Entry(ORDER, cancelled, 0.0), 1.0)
    assert world.heard == [cancelled]

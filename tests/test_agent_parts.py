"""The parts an agent node is made of, each on its own: the lock-step clock's waits, the
real-time clock's carried states, the link faults and the transport's record."""

from __future__ import annotations

import asyncio
import threading

import pytest

from agent.clock import LockstepClock, RealtimeClock
from agent.fault_inject import FaultInjector
from agent.faults import LinkFaults
from agent.inbox import CONTEST_HOLD_S, Inbox, Receiver
from agent.transport import Transport
from wire import keys
from wire.payloads import Pose, State, encode
from wire.traffic import TrafficCounter


class FakeInbox:
    """What a lock-step wait reads: one key that arrives when ``arrive`` is called."""

    def __init__(self) -> None:
        self.arrived = asyncio.Event()
        self.have: set[str] = set()
        self.late: list[str] = []
        self.advanced: list[float] = []

    def missing(self, inputs: list[tuple[str, str]], t: float) -> list[str]:
        return [k for _, k in inputs if k not in self.have and k not in self.late]

    def mark_late(self, late: list[str]) -> None:
        self.late += late

    def advance(self, t: float) -> bool:
        self.advanced.append(t)
        return False


def test_a_lock_step_wait_returns_once_its_input_arrives_and_gives_up_on_a_dead_one() -> None:
    async def body() -> None:
        clock = LockstepClock(0.5, 0.2, 0.0, "r1", 1e-9)
        clock.stop = asyncio.Event()
        inbox = FakeInbox()

        async def arrive() -> None:
            await asyncio.sleep(0)
            inbox.have.add("a")
            inbox.arrived.set()

        task = asyncio.ensure_future(arrive())
        assert await clock.wait(inbox, [(keys.STATE, "a")], 1.0)
        await task
        assert clock.timeouts == 0 and inbox.late == []
        # "b" never comes: one timeout, then it is late and the next wait does not wait for it
        assert not await clock.wait(inbox, [(keys.STATE, "a"), (keys.STATE, "b")], 1.1)
        assert clock.timeouts == 1 and inbox.late == ["b"]
        assert await clock.wait(inbox, [(keys.STATE, "b")], 1.2)
        await clock.start(inbox, [(keys.POSE, "a")], 1.3)
        assert inbox.advanced == [1.3] and clock.timeouts == 1

    asyncio.run(body())


def test_the_lock_step_clock_goes_by_frames_and_the_real_time_one_carries_states() -> None:
    ls = LockstepClock(0.5, 2.0, 4.0, "r1", 1e-9)
    assert ls.now() == 4.0 and not ls.starved()  # never ticked: not starved
    ls.begin_frame(4.1, 0.0)  # ticked long ago (monotonic 0): the world went on without it
    assert ls.now() == 4.1 and ls.starved()
    entry = (State(0.0, 0.0, 0.0, 0.0, 4.0), 0.0)
    assert ls.fresh(entry, 4.5) and not ls.fresh(entry, 4.6)
    assert not ls.pose_current(entry, 4.1)  # fresh, but not this frame's pose
    assert ls.cmd_stamp(4.1, 3.0) == 4.1
    rt = RealtimeClock(0.5, 0.0)
    moving = {"k": State(0.0, 0.0, 1.0, 0.0, 10.0, 0.0)}
    x, y, ux, uy, theta = rt.align(moving, 10.2)["k"]  # (x, y, ux, uy, theta) at 10.2
    assert (x, y, ux, uy, theta) == (pytest.approx(0.2), 0.0, 1.0, 0.0, 0.0)
    assert rt.align(moving, 20.0)["k"][0] == pytest.approx(0.5)  # never beyond the stale limit
    assert ls.align(moving, 10.2)["k"] == (0.0, 0.0, 1.0, 0.0, 0.0)  # lock-step: as it came
    assert rt.cmd_stamp(None, 3.0) == 3.0
    sent: list[str] = []
    ls.state_before(lambda: sent.append("ls"))
    rt.state_before(lambda: sent.append("rt-before"))
    rt.state_after(lambda: sent.append("rt"))
    assert sent == ["ls", "rt"]


def test_the_fault_injector_counts_losses_and_lock_step_stops_waiting_for_a_lost_message() -> None:
    stored: list[tuple[str, bytes]] = []
    inj = FaultInjector(LinkFaults(drop=0.999999), "r1", 0.05, True, threading.Lock(),
                        lambda k, p: stored.append((k, p)))

    async def body() -> None:
        loop = asyncio.get_running_loop()
        payload = encode(State(0.0, 0.0, 0.0, 0.0, 2.0))
        inj.sample(loop, keys.STATE, lambda b: State(0.0, 0.0, 0.0, 0.0, 2.0), "k", payload,
                   lambda k, p: stored.append((k, p)))
        await asyncio.sleep(0)

    asyncio.run(body())
    assert stored == [] and inj.dropped[keys.STATE] == 1
    assert inj.lost_since("k", inj.need(keys.STATE, 2.0)) and not inj.lost_since("k", 2.05)
    assert inj.need(keys.POSE, 2.0) == 2.0  # poses are never faulted


class Pub:
    def __init__(self) -> None:
        self.put: list = []

    def put_message(self, msg) -> None:
        self.put.append(msg)


def test_the_transport_publishes_only_where_declared_and_forgets_a_subscriber() -> None:
    t = Transport(None, TrafficCounter("p"))
    assert not t.publish("a", 1)
    pub = Pub()
    t.adopt("a", pub)
    assert t.publish("a", 1) and pub.put == [1]
    t.keep("s", "sub-s")
    t.keep(None, "token")
    assert t.forget("s") == "sub-s"
    assert t.handles() == ["token", pub]
    t.clear()
    assert t.handles() == []


def test_a_pose_stamped_ahead_of_the_clock_cannot_make_the_genuine_ones_after_it_older() -> None:
    # the +90 ms attack: one pose stamped inside the tolerance but ahead of the clock used to
    # become "the last used" and refuse every genuine pose for the next 90 ms (a stream of them:
    # for good); the inbox now records the stamp no later than its clock (wire.stamps.used_stamp)
    clock = [100.0]
    rx = Receiver(lambda: clock[0], lambda: False, 0.1, 0.25, 0.5)
    inbox = Inbox("a1", rx, TrafficCounter("warehouse"), LinkFaults(), (0.05, False),
                  threading.Lock(), polled=True)
    accept = inbox.acceptor(keys.POSE)
    key = keys.pose_key("warehouse", "a1")
    forged = (Pose(1.0, 0.0, 0.0, 100.09), 100.0)
    assert accept(key, forged, None)
    clock[0] = 100.02
    genuine = (Pose(1.0, 0.0, 0.0, 100.01), 100.02)  # captured after the forged one arrived
    assert accept(key, genuine, forged)
    assert inbox.stamps.snapshot().get(keys.POSE, {}).get("older", 0) == 0
    stale_replay = (Pose(1.0, 0.0, 0.0, 99.99), 100.02)  # still refused: older than used
    assert not accept(key, stale_replay, genuine)


def test_a_second_source_on_the_pose_holds_the_robot_until_it_has_been_quiet_for_a_while() -> None:
    # real time: a genuine pose refused as older that disagrees with the kept (forged) one is a
    # second source on the key; the robot stays commanded zero, and tells no neighbour its
    # position, until CONTEST_HOLD_S after the last such pose (not just the tick after it)
    clock = [100.0]
    inbox = _pose_inbox(clock)
    accept, key = inbox.acceptor(keys.POSE), keys.pose_key("warehouse", "a1")
    forged = (Pose(1.2, 0.0, 0.0, 100.09), 100.0)  # walked 0.2 m from the robot, +90 ms
    assert accept(key, forged, None) and not inbox.contested()
    clock[0] = 100.03
    genuine = (Pose(1.0, 0.0, 0.0, 100.02), 100.03)  # captured before the forged one arrived
    assert not accept(key, genuine, forged)
    assert inbox.contested() and inbox.take_implausible()
    clock[0] = 100.03 + 0.9 * CONTEST_HOLD_S
    assert inbox.contested()  # held, though no input broke physics since
    clock[0] = 100.03 + 1.1 * CONTEST_HOLD_S
    assert not inbox.contested()
    # lock-step knows one source (the simulated world's): nothing is ever contested there
    clock[0] = 100.0
    lockstep = Inbox("a1", Receiver(lambda: clock[0], lambda: False, 0.1, 1.0, 0.5),
                     TrafficCounter("warehouse"), LinkFaults(), (0.05, True), threading.Lock(),
                     polled=True)
    accept = lockstep.acceptor(keys.POSE)
    assert accept(key, forged, None)
    clock[0] = 100.03
    assert not accept(key, genuine, forged)  # refused as a jump, as before
    assert not lockstep.contested()


def _pose_inbox(clock: list[float]) -> Inbox:
    # stale after 1 s (a 5 fps camera): the kept pose stays fresh through the re-acquire run
    rx = Receiver(lambda: clock[0], lambda: False, 0.1, 1.0, 0.5)
    return Inbox("a1", rx, TrafficCounter("warehouse"), LinkFaults(), (0.05, False),
                 threading.Lock(), polled=True)


def _walk_jumped(inbox: Inbox, clock: list[float], kept, moving_after: int | None) -> list[bool]:
    """Poses 5 m from the kept one, agreeing with each other, every 0.1 s: which were taken."""
    accept, key, taken = inbox.acceptor(keys.POSE), keys.pose_key("warehouse", "a1"), []
    for k in range(6):
        clock[0] += 0.1
        entry = (Pose(5.0, 0.0, 0.0, clock[0]), clock[0])
        taken.append(accept(key, entry, kept))
        if taken[-1]:
            kept = entry
        inbox.note_command(moving_after is not None and k == moving_after)
    return taken


def test_a_marker_that_jumped_is_reacquired_only_while_its_robot_was_commanded_zero() -> None:
    clock = [100.0]
    inbox = _pose_inbox(clock)
    kept = (Pose(0.0, 0.0, 0.0, 100.0), 100.0)
    assert inbox.acceptor(keys.POSE)(keys.pose_key("warehouse", "a1"), kept, None)
    taken = _walk_jumped(inbox, clock, kept, moving_after=None)
    assert taken.index(True) >= 2 and inbox.reacquired == 1  # a few agreeing poses, then taken
    clock2 = [200.0]
    moved = _pose_inbox(clock2)
    kept2 = (Pose(0.0, 0.0, 0.0, 200.0), 200.0)
    assert moved.acceptor(keys.POSE)(keys.pose_key("warehouse", "a1"), kept2, None)
    assert not any(_walk_jumped(moved, clock2, kept2, moving_after=0))  # it moved: never taken
    assert moved.reacquired == 0 and moved.implausible[keys.POSE] == 6

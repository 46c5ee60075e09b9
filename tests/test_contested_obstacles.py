"""Two sources on the obstacle list: the robot avoids every obstacle either reports, moving ones
moved on to now, instead of stopping in a moving obstacle's way (agent.plausibility's rivals,
agent.inbox). A forger can at worst add a phantom; it cannot take a real obstacle away."""

from __future__ import annotations

import math
import threading

from hypothesis import given, settings
from hypothesis import strategies as st

from agent.faults import LinkFaults
from agent.inbox import Inbox, Receiver
from agent.plausibility import (
    JUMP_MARGIN_M,
    MAX_RIVALS,
    OBSTACLE_HOLD_S,
    RIVAL_HOLD_S,
    ObstacleMemory,
    ObstacleRivals,
    held_obstacle,
    moved_on,
    obstacles_agree,
    rival_obstacles,
    shapes_of_all,
    sighting_agrees,
)
from wire import keys
from wire.payloads import SHAPE_BOX, ObstacleMsg, Obstacles, ShapeMsg, encode
from wire.traffic import TrafficCounter

KEY = keys.obstacles_key("warehouse")
SHELF = ShapeMsg("shelf", SHAPE_BOX, 2.0, 1.0, 0.5, 0.3, 0.0, 0.2)
CRATE = ObstacleMsg("crate", 4.5, 0.05, -0.05, 0.0, 0.3)


def _inbox(clock: list[float], lockstep: bool = False) -> Inbox:
    rx = Receiver(lambda: clock[0], lambda: False, 0.1, 0.25, 0.5)
    return Inbox("r1", rx, TrafficCounter("warehouse"), LinkFaults(), (0.05, lockstep),
                 threading.Lock(), polled=True)


def _at(o: ObstacleMsg, t: float) -> ObstacleMsg:
    """``o`` (seen at time 0) where its velocity has taken it at ``t``."""
    return ObstacleMsg(o.id, o.x + o.vx * t, o.y + o.vy * t, o.vx, o.vy, o.ds)


def _put(inbox: Inbox, clock: list[float], now: float, msg: Obstacles) -> None:
    clock[0] = now
    inbox.offer(keys.OBSTACLES, KEY, encode(msg))


def _kept(inbox: Inbox) -> Obstacles:
    entry = inbox.latest(keys.OBSTACLES, KEY)
    assert entry is not None
    return entry[0]


def test_a_list_stamped_before_the_kept_one_that_disagrees_is_avoided_and_the_robot_drives_on():
    clock = [100.0]
    inbox = _inbox(clock)
    forged = Obstacles(100.09, ())  # empty, stamped 90 ms ahead (inside the clock tolerance)
    _put(inbox, clock, 100.0, forged)
    genuine = Obstacles(100.02, (_at(CRATE, 100.02),))
    _put(inbox, clock, 100.03, genuine)
    assert _kept(inbox) == forged  # the genuine list is refused as the second source ...
    assert inbox.implausible == {keys.OBSTACLES: 1}  # ... and counted
    # ... but no tick stops for it: the robot avoids the genuine crate, moved on to now
    assert not inbox.take_implausible() and not inbox.contested()
    assert inbox.obstacle_rivals() == (genuine,)
    (crate,) = rival_obstacles(inbox.obstacle_rivals(), 100.05)
    expect = _at(CRATE, 100.05)
    assert math.isclose(crate.x, expect.x) and crate.ds == CRATE.ds and crate.vx == CRATE.vx
    # the source's next list replaces its last; once it is quiet for the hold it is forgotten
    later = Obstacles(100.07, (_at(CRATE, 100.07),))
    _put(inbox, clock, 100.08, later)
    assert inbox.obstacle_rivals() == (later,)
    clock[0] = 100.08 + 0.9 * RIVAL_HOLD_S
    assert inbox.obstacle_rivals() == (later,)
    clock[0] = 100.08 + 1.1 * RIVAL_HOLD_S
    assert inbox.obstacle_rivals() == ()


def test_a_newer_list_that_moves_an_obstacle_or_drops_a_wall_makes_the_kept_one_a_rival():
    # a forger stamping its lists at the right time replaces the kept list: the one it replaces
    # is kept avoided, since which of the two is genuine cannot be told
    clock = [100.0]
    inbox = _inbox(clock)
    genuine = Obstacles(100.0, (_at(CRATE, 100.0),), (SHELF,))
    _put(inbox, clock, 100.01, genuine)
    moved = ObstacleMsg("crate", 3.0, 2.0, -0.05, 0.0, 0.3)  # 2.4 m from where it is
    forged = Obstacles(100.03, (moved,), ())
    _put(inbox, clock, 100.03, forged)
    assert _kept(inbox) == forged and inbox.obstacle_rivals() == (genuine,)
    assert inbox.implausible == {keys.OBSTACLES: 1} and not inbox.take_implausible()
    assert shapes_of_all(forged, inbox.obstacle_rivals()) == (SHELF,)
    # the same source's lists moving as their velocity says are no second source
    clock2 = [100.0]
    honest = _inbox(clock2)
    for k in range(40):
        t = 100.0 + 0.05 * k
        _put(honest, clock2, t + 0.01, Obstacles(t, (_at(CRATE, t),), (SHELF,)))
    assert honest.implausible == {} and honest.obstacle_rivals() == ()


def test_more_sources_than_tracked_stop_the_robot_until_they_have_been_quiet_for_the_hold():
    rivals = ObstacleRivals()
    for k in range(MAX_RIVALS):  # each its own source: its phantom elsewhere
        rivals.offer(Obstacles(10.0, (ObstacleMsg("p", float(k), 0.0, 0.0, 0.0, 0.3),)), 10.0)
    assert len(rivals.current(10.0)) == MAX_RIVALS and not rivals.overflowed(10.0)
    rivals.offer(Obstacles(10.0, (ObstacleMsg("p", 9.0, 0.0, 0.0, 0.0, 0.3),)), 10.01)
    assert len(rivals.current(10.01)) == MAX_RIVALS and rivals.overflowed(10.01)
    assert rivals.overflowed(10.01 + 0.9 * RIVAL_HOLD_S)
    assert not rivals.overflowed(10.01 + 1.1 * RIVAL_HOLD_S)
    # the inbox stops the robot meanwhile (counted 'contested' by the tick)
    clock = [100.0]
    inbox = _inbox(clock)
    _put(inbox, clock, 100.0, Obstacles(100.09, ()))
    for k in range(MAX_RIVALS + 1):
        phantom = ObstacleMsg("p", float(k), 0.0, 0.0, 0.0, 0.3)
        _put(inbox, clock, 100.01 + 0.001 * k, Obstacles(100.0, (phantom,)))
    assert inbox.contested()


def test_lock_step_knows_one_source_and_tracks_no_rival():
    clock = [100.0]
    inbox = _inbox(clock, lockstep=True)
    _put(inbox, clock, 100.0, Obstacles(100.0, (_at(CRATE, 100.0),), (SHELF,)))
    _put(inbox, clock, 100.05, Obstacles(100.05, (ObstacleMsg("crate", 0.0, 0.0, 0, 0, 0.3),)))
    assert inbox.implausible == {} and inbox.obstacle_rivals() == () and not inbox.contested()


@given(vx=st.floats(-0.5, 0.5), vy=st.floats(-0.5, 0.5), t0=st.floats(0.0, 100.0),
       dt=st.floats(-1.0, 1.0), noise=st.floats(0.0, 0.99 * JUMP_MARGIN_M))
def test_one_obstacle_moving_as_its_velocity_says_always_agrees_with_itself(vx, vy, t0, dt, noise):
    o = ObstacleMsg("o", 1.0, 2.0, vx, vy, 0.3)
    a, b = _at(o, t0), _at(o, t0 + dt)
    b = ObstacleMsg("o", b.x + noise, b.y, vx, vy, 0.3)  # the camera's noise
    assert sighting_agrees(a, t0, b, t0 + dt)
    assert obstacles_agree(Obstacles(t0, (a,)), Obstacles(t0 + dt, (b,)))


@given(off=st.floats(1.01 * JUMP_MARGIN_M, 10.0), angle=st.floats(-math.pi, math.pi),
       dt=st.floats(-0.25, 0.25), shrink=st.floats(0.0, 0.29))
def test_an_obstacle_moved_beyond_the_margin_or_shrunk_disagrees(off, angle, dt, shrink):
    a = ObstacleMsg("o", 1.0, 2.0, 0.2, 0.0, 0.3)
    b = _at(a, dt)
    moved = ObstacleMsg("o", b.x + off * math.cos(angle), b.y + off * math.sin(angle),
                        0.2, 0.0, 0.3)
    assert not sighting_agrees(a, 0.0, moved, dt) and not sighting_agrees(moved, dt, a, 0.0)
    later = _at(a, abs(dt))
    assert not sighting_agrees(a, 0.0, ObstacleMsg("o", later.x, later.y, 0.2, 0.0, shrink),
                               abs(dt))


def test_a_camera_holding_an_obstacle_it_lost_stops_no_robot():
    # camera_service: an obstacle unseen for a few frames keeps its last position and grows its
    # Ds by its speed times its age: one source. Re-seen, it is back where it is with its own
    # Ds: a shrink no forger may make unseen, so the held list stays avoided for the hold
    clock = [100.0]
    inbox = _inbox(clock)
    last = _at(CRATE, 0.45)
    for k in range(60):
        t = 100.0 + 0.05 * k
        seen = _at(CRATE, t - 100.0)
        if 10 <= k < 20:  # lost: held at its last sighting (k = 9), grown
            seen = ObstacleMsg("crate", last.x, last.y, CRATE.vx, CRATE.vy,
                               CRATE.ds + 0.05 * (t - 100.45))
        _put(inbox, clock, t + 0.01, Obstacles(t, (seen,), (SHELF,)))
        assert not inbox.contested() and not inbox.take_implausible()
        if k < 20:
            assert inbox.implausible == {} and inbox.obstacle_rivals() == ()
        elif t + 0.01 < 101.01 + RIVAL_HOLD_S:
            assert len(inbox.obstacle_rivals()) == 1
    assert inbox.implausible == {keys.OBSTACLES: 1} and inbox.obstacle_rivals() == ()


ATTACKS = st.sampled_from(["empty", "moved", "shrunk", "phantom", "no-walls"])


def _forged(kind: str, genuine: ObstacleMsg, stamp: float, off: float) -> Obstacles:
    """The forger's list of ``kind`` stamped ``stamp``, beside the genuine ``genuine``."""
    if kind == "empty":
        return Obstacles(stamp, ())
    if kind == "moved":
        return Obstacles(stamp, (ObstacleMsg(genuine.id, genuine.x + off, genuine.y - off,
                                             genuine.vx, genuine.vy, genuine.ds),), (SHELF,))
    if kind == "shrunk":
        return Obstacles(stamp, (ObstacleMsg(genuine.id, genuine.x, genuine.y, genuine.vx,
                                             genuine.vy, 0.01),), (SHELF,))
    if kind == "phantom":
        return Obstacles(stamp, (ObstacleMsg("ghost", 0.0, 0.0, 0.0, 0.0, 0.3),), (SHELF,))
    return Obstacles(stamp, (genuine,), ())


def _avoided(inbox: Inbox, memory: ObstacleMemory, now: float
             ) -> tuple[list[tuple[float, float, float]], tuple[ShapeMsg, ...]]:
    """What a tick at ``now`` avoids, as agent.tick composes it: the kept list's obstacles, the
    held ones grown, every rival's moved on; the walls of all."""
    kept = _kept(inbox)
    memory.update(kept)
    discs = [(o.x, o.y, o.ds) for o in kept.obstacles]
    discs += [(h.x, h.y, h.ds) for h in (held_obstacle(o, age, 0.0, 0.0)
                                         for o, age in memory.held(now))]
    rivals = inbox.obstacle_rivals()
    discs += [(o.x, o.y, o.ds) for o in rival_obstacles(rivals, now)]
    return discs, shapes_of_all(kept, rivals)


@settings(max_examples=60, deadline=None)
@given(kind=ATTACKS, ahead=st.floats(0.0, 0.099), latency=st.floats(0.0, 0.04),
       off=st.floats(0.06, 2.0), vx=st.floats(-0.5, 0.5), vy=st.floats(-0.5, 0.5),
       forger_first=st.booleans())
def test_a_forger_beside_the_camera_never_takes_a_real_obstacle_or_wall_away(
        kind, ahead, latency, off, vx, vy, forger_first):
    # the genuine camera: a moving crate and a shelf every 50 ms, arriving `latency` late; for
    # each a forged list stamped `ahead` of the clock; 3 s, longer than a missing obstacle is
    # held. After every arrival the genuine crate where it is now (its Ds, plus how far it can
    # have moved since a fresh list's stamp and the camera's margin) lies inside a disc the
    # robot avoids, and the shelf stays a wall
    crate = ObstacleMsg("crate", 2.0, 0.0, vx, vy, 0.3)
    speed = math.hypot(vx, vy)
    slack = JUMP_MARGIN_M + speed * 0.25 + 1e-6  # stale_after: a kept list is at most this old
    clock = [100.0]
    inbox, memory = _inbox(clock), ObstacleMemory()
    for k in range(60):
        t = 100.0 + 0.05 * k
        genuine = Obstacles(t, (_at(crate, t - 100.0),), (SHELF,))
        forged = _forged(kind, genuine.obstacles[0], t + latency + ahead, off)
        arrivals = [(t + latency + (0.0 if forger_first else 0.001), genuine),
                    (t + latency + (0.001 if forger_first else 0.0), forged)]
        # the attack starts once the robot has had the camera's first list
        for now, msg in sorted(arrivals if k else arrivals[:1], key=lambda p: p[0]):
            _put(inbox, clock, now, msg)
            discs, shapes = _avoided(inbox, memory, now)
            true = _at(crate, now - 100.0)
            assert any(math.hypot(x - true.x, y - true.y) + true.ds <= ds + slack
                       for x, y, ds in discs), (kind, k, discs)
            assert SHELF in shapes
    assert not inbox.contested()  # ... and it drove on: two sources stop no robot
    assert OBSTACLE_HOLD_S < 60 * 0.05  # the run outlasts the hold of a missing obstacle


def test_a_rival_is_moved_on_by_its_velocity_and_never_back():
    o = ObstacleMsg("o", 1.0, 0.0, 0.5, 0.0, 0.3)
    assert moved_on(o, 0.2).x == 1.1 and moved_on(o, -0.09).x == 1.0

"""The footprint planner (geometry.footprint_plan) and the replanning rules (leader.routing):
a returned route's footprint (every member's body at its slot, and the load's outline) never
comes nearer a wall, shelf or circle than its safe distance, checked exactly along every leg;
a long formation turns where only its length fits; no route says why."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.body import motion_of
from geometry.ellipse import Ellipse
from geometry.footprint_plan import (
    NARROW,
    NO_WAY,
    PLAN_MARGIN,
    SEARCH,
    Body,
    FootprintPlan,
    load_outline,
    plan_aside,
    plan_footprint,
)
from geometry.shapes import box, segment, shape_distance
from leader.navigation import HEADING_TOLERANCE, SETTLED_SPEED, Follower, heading_tolerance
from leader.routing import (
    GIVING,
    LANES,
    PACE,
    PROGRESS,
    REACHED,
    STALLED,
    STILL,
    UNREACHABLE,
    GiveWayJob,
    Other,
    PlanJob,
    Reason,
    Replanner,
    StillThings,
    Thing,
    blockers,
    give_way_job,
    lane_circles,
    lanes,
    oncoming,
    plan_job,
)
from simulator.motion import REVERSAL_SPEED

LINE = Body(tuple((-0.6 + 0.3 * k, 0.0) for k in range(5)), radius=0.1, margin=0.0)


def _placed(pose, p):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (pose[0] + c * p[0] - s * p[1], pose[1] + s * p[0] + c * p[1])


def _legs(start, route, step=0.02):
    """Poses along the route: each leg a straight move turning as it goes (the short way)."""
    prev = start
    for nxt in route:
        d = math.dist(prev[:2], nxt[:2])
        left = math.radians(20.0)  # the rigid motion's rule: near half a turn it goes left
        turn = (nxt[2] - prev[2] + math.pi - left) % (2.0 * math.pi) - math.pi + left
        n = max(1, int(d / step), int(abs(turn) * 0.8 / step))
        for k in range(n + 1):
            f = k / n
            yield (prev[0] + f * (nxt[0] - prev[0]), prev[1] + f * (nxt[1] - prev[1]),
                   prev[2] + f * turn)
        prev = nxt


def _clearance(body, pose, shapes, circles):
    """The smallest margin of the footprint at ``pose`` (< 0: it touches something)."""
    worst = math.inf
    slots = [_placed(pose, p) for p in body.slots]
    outline = [_placed(pose, p) for p in load_outline(body)]
    n = len(outline)
    edge_pts = [(a[0] + (b[0] - a[0]) * f / 20, a[1] + (b[1] - a[1]) * f / 20)
                for k in range(n) for a, b in [(outline[k], outline[(k + 1) % n])] for f in range(21)]
    for sh in shapes:
        worst = min([worst] + [shape_distance(x, y, sh)[0] - sh.ds for x, y in slots]
                    + [shape_distance(x, y, sh)[0] for x, y in edge_pts])
    for ox, oy, ds in circles:
        worst = min([worst] + [math.dist((x, y), (ox, oy)) - ds for x, y in slots]
                    + [math.dist((x, y), (ox, oy)) - (ds - body.radius) for x, y in edge_pts])
    return worst


def _aisle():
    """Two shelf blocks with a 1.8 m aisle between them along x."""
    return [box("n", (0.0, 3.4), (6.0, 5.0), 0.0, 0.15), box("s", (0.0, -3.4), (6.0, 5.0), 0.0, 0.15)]


def test_a_line_crosswise_to_an_aisle_turns_into_it_and_back():
    body = Body(tuple((0.0, -0.75 + 0.3 * k) for k in range(6)), radius=0.105, margin=0.09)
    plan = plan_footprint((-5.0, 0.0, 0.0), (5.0, 0.0, 0.0), body, _aisle())
    assert plan.reason == "" and plan.route[-1] == (5.0, 0.0, 0.0)
    inside = [th for x, _y, th in plan.route if -3.0 < x < 3.0]
    assert inside and all(abs(math.sin(th)) > 0.5 for th in inside)  # turned well away from crosswise
    for pose in _legs((-5.0, 0.0, 0.0), plan.route):
        assert _clearance(body, pose, _aisle(), ()) > 0.0


def test_a_large_hall_is_planned_again_on_the_fine_lattice_where_the_coarse_one_is_shut():
    """A hall of 22 x 13 m (over Grid.fine_cells fine cells: planned on the 0.1 m lattice) whose one
    way north is a 1.68 m gap in a shelf row; a hexagon of six robots fits it turned, by less
    than the coarse lattice's Search.move_need h a side (a warehouse draw's hall)."""
    hall = [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(
        [((-11, -6.5), (11, -6.5)), ((11, -6.5), (11, 6.5)), ((11, 6.5), (-11, 6.5)),
         ((-11, 6.5), (-11, -6.5))])]
    row = [box("west", (-5.92, 0.0), (10.16, 0.9), 0.0, 0.15),  # x -11.0 .. -0.84
           box("east", (5.92, 0.0), (10.16, 0.9), 0.0, 0.15)]  # x 0.84 .. 11.0
    hexagon = Body(tuple((0.5 * math.cos(k * math.pi / 3), 0.5 * math.sin(k * math.pi / 3))
                         for k in range(6)), radius=0.105, margin=0.15)
    start, goal = (0.0, -3.0, 0.0), (0.0, 3.0, 0.0)
    coarse = plan_footprint(start, goal, hexagon, hall + row, h=0.1)
    assert coarse.route == ()  # shut at 0.1 m
    plan = plan_footprint(start, goal, hexagon, hall + row)
    assert plan.reason == "" and plan.route[-1] == goal, plan
    assert plan.expanded > coarse.expanded  # the coarse search ran first
    for pose in _legs(start, plan.route):
        assert _clearance(hexagon, pose, hall + row, ()) > 0.0


def test_no_route_into_a_closed_room_says_why():
    room = [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(
        [((1, -1), (1, 1)), ((1, 1), (3, 1)), ((3, 1), (3, -1)), ((3, -1), (1, -1))])]
    plan = plan_footprint((-3.0, 0.0, 0.0), (2.0, 0.0, 0.0), LINE, room)
    assert plan.route == () and "no way" in plan.reason


KEEP = 0.04  # [m] what a formation keeps beyond Ds itself (epsilon)
NARROW_SHAPES = {  # crosswise to the way east: the footprint must turn by a quarter to pass
    "line": ((0.0, -0.45), (0.0, 0.0), (0.0, 0.45)),
    "triangle": ((0.117, -0.3828), (0.117, 0.5172), (-0.2339, -0.1343)),  # edges 0.9, 0.74, 0.43 m
    "pentagon": tuple((0.4 * math.cos(2 * math.pi * k / 5), 0.4 * math.sin(2 * math.pi * k / 5))
                      for k in range(5)),  # a robot ahead: 0.76 m across, 0.72 m turned
}


def _narrow_scene(body: Body, side: float, yaw: float):
    """A 12 x 7 m hall closed but for a slot between two shelf blocks (2 m long) that the
    footprint, turned a quarter, fits with ``side`` a side beyond Ds; start and goal 3.5 m either
    side of it; all turned by ``yaw`` about the slot's centre."""
    turned = [(y, -x) for x, y in body.slots]
    half = (max(y for _x, y in turned) - min(y for _x, y in turned)) / 2 + 0.15 + side
    c, s = math.cos(yaw), math.sin(yaw)

    def at(x, y):
        return (c * x - s * y, s * x + c * y)

    shapes = [box("block-n", at(0.0, (half + 3.5) / 2), (2.0, 3.5 - half), yaw, 0.15),
              box("block-s", at(0.0, -(half + 3.5) / 2), (2.0, 3.5 - half), yaw, 0.15)]
    corners = [at(-6.0, -3.5), at(6.0, -3.5), at(6.0, 3.5), at(-6.0, 3.5)]
    shapes += [segment(f"hall{k}", corners[k], corners[(k + 1) % 4], 0.15) for k in range(4)]
    return shapes, (*at(-3.5, 0.6), yaw), (*at(3.5, -0.3), yaw - math.pi / 2)


@pytest.mark.parametrize("yaw", [0.0, 0.3])
@pytest.mark.parametrize("shape", sorted(NARROW_SHAPES))
def test_a_slot_the_footprint_fits_by_the_narrow_clearance_is_planned_through(shape, yaw):
    """A slot the footprint fits turned by what it keeps plus NARROW.clearance a side, which the
    lattice alone shuts (at any angle to the lattice): planned, and every pose on the way keeps
    what the formation keeps."""
    body = Body(NARROW_SHAPES[shape], radius=0.105, margin=PLAN_MARGIN + KEEP)
    shapes, start, goal = _narrow_scene(body, KEEP + NARROW.clearance, yaw)
    assert plan_footprint(start, goal, body, shapes, h=0.05).reason == NO_WAY
    plan = plan_footprint(start, goal, body, shapes)
    assert plan.reason == "" and plan.route[-1] == goal, plan
    assert min(_clearance(body, pose, shapes, ()) for pose in _legs(start, plan.route)) >= KEEP


def test_a_slot_narrower_than_what_the_formation_keeps_has_no_route():
    body = Body(NARROW_SHAPES["triangle"], radius=0.105, margin=PLAN_MARGIN + KEEP)
    shapes, start, goal = _narrow_scene(body, KEEP - 0.01, 0.0)
    assert plan_footprint(start, goal, body, shapes).reason == NO_WAY


@pytest.mark.slow
def test_a_formation_alone_in_the_lattice_s_way_is_given_way_to_not_gone_round_by_a_narrow_way():
    """A wall with a wide door, where another formation stands (a movable circle), and a slot
    the footprint fits only by the narrow pass: no route (the formation in the door is given way
    to, leader.routing); the same circle standing still for good (a pillar): the narrow slot."""
    body = Body(NARROW_SHAPES["triangle"], radius=0.105, margin=PLAN_MARGIN + KEEP)
    half = 0.3509 / 2 + 0.15 + KEEP + NARROW.clearance  # the slot at y = -2, the door at y = 2
    cuts = [-3.5, -2.0 - half, -2.0 + half, 1.2, 2.8, 3.5]
    wall = [segment(f"w{k}", (0.0, cuts[2 * k]), (0.0, cuts[2 * k + 1]), 0.15) for k in range(3)]
    hall = [segment("n", (-5.0, 3.5), (5.0, 3.5), 0.15), segment("s", (-5.0, -3.5), (5.0, -3.5), 0.15),
            segment("w", (-5.0, -3.5), (-5.0, 3.5), 0.15), segment("e", (5.0, -3.5), (5.0, 3.5), 0.15)]
    other = (0.0, 2.0, 0.6)
    start, goal = (-3.0, 0.0, 0.0), (3.0, 0.0, -math.pi / 2)
    things = (start, goal, body, wall + hall, [other])
    assert plan_footprint(*things, limit=100_000, movable=[other]).route == ()
    plan = plan_footprint(*things, limit=100_000)
    assert plan.reason == "" and plan.route[-1] == goal
    assert min(y for _x, y, _th in plan.route) < -1.5  # by the slot
    assert min(_clearance(body, pose, wall + hall, [other]) for pose in _legs(start, plan.route)) >= KEEP


def _slot_by_mates():
    """A pallet's last free slot, by a shelf: a robot (radius 0.105, keeping 0.1 as a unicycle
    formation of one does) to its slot past three teammates standing at theirs (circles of two
    radii), a resting beam either side of the pallet's rack (a drawn hall of the lifelong Monte
    Carlo). Its one way in runs round the east teammate and along the shelf, tight all the way;
    the loose search first tries between the teammates, up to the slot itself."""
    shapes = [box("shelf", (3.7779, 0.0), (5.3319, 0.8512), 0.0, 0.15),
              box("beam-w", (1.9779, -0.9756), (1.4, 0.3), 0.0, 0.15),
              box("beam-e", (5.5779, -0.9756), (1.4, 0.3), 0.0, 0.15)]
    mates = [(3.4858, -1.1693, 0.21), (4.0777, -1.1694, 0.21), (3.4932, -0.7711, 0.21)]
    body = Body(((0.0, 0.0),), radius=0.105, margin=PLAN_MARGIN + 0.1)
    return body, shapes, mates, (2.931, -1.322, 0.0), (4.0729, -0.7806, 0.0)


def test_a_slot_whose_last_stretch_is_tight_is_reached_by_another_way_where_the_first_is_shut():
    """The narrow pass shuts a loose way whose tight stretch has no way, and searches again:
    never the start or the goal themselves, or no later way could reach them."""
    body, shapes, mates, start, goal = _slot_by_mates()
    plan = plan_footprint(start, goal, body, shapes, mates)
    assert plan.reason == "" and plan.route[-1] == goal, plan
    assert max(x for x, _y, _th in plan.route) > 4.3  # round the east teammate
    assert min(_clearance(body, pose, shapes, mates) for pose in _legs(start, plan.route)) >= 0.1
    # teammates that may move out of the way are waited for, never squeezed past
    assert plan_footprint(start, goal, body, shapes, mates, movable=mates).route == ()


def test_teammates_standing_at_their_slots_are_bodies_to_go_round_not_formations_to_wait_for():
    """A gathering robot's plan (:attr:`Replanner.mates`): its teammates at their slots are
    neither parked formations (no give-way for them) nor movable (the narrow pass goes past
    them); any other formation still is both."""
    body, shapes, mates, start, goal = _slot_by_mates()
    r = Replanner(body, 0.0, goal, shapes)
    r.mates = frozenset({"r2", "r3", "r4"})
    things = tuple((f"formation/r{k}", c) for k, c in zip((2, 4, 3), mates, strict=True)) + (
        ("formation/r9", (0.0, -2.5, 0.485)),)
    job = r.begin(0.0, start, things)
    assert job.formations == (("r9", (0.0, -2.5, 0.485)),)
    assert job.movable == ((0.0, -2.5, 0.485),)
    assert job.circles == tuple(c for _n, c in things)
    assert job.mates == tuple((c, c) for _n, c in things[:3])  # two radii already
    res = plan_job(job)
    assert res.plan.route[-1] == goal and res.blocked_by == ()
    # as formations of one (their ellipses' reach) the teammates shut the slot by the shelf: the
    # route goes past them as robots
    wide = tuple((n, (c[0], c[1], 0.485)) for n, c in things[:3]) + things[3:]
    job = r.begin(0.0, start, wide)
    assert job.mates == tuple(((c[0], c[1], 0.485), c) for c in mates)
    res = plan_job(job)
    assert res.plan.route[-1] == goal and res.blocked_by == ()


def test_a_gathering_robot_goes_round_its_teammates_ellipses_where_a_way_does_not_between():
    """Teammates standing at three corners of a pallet (a drawn unicycle hall of the lifelong
    Monte Carlo), their ellipses 0.74 m apart, and a robot north of the pallet bound for the
    fourth corner, by the shelf: past the teammates as robots its way runs between two of them,
    where its rows keep it off their ellipses (it stood there for good); planned round their
    ellipses first (:func:`leader.routing.round_mates`), it goes round the east one, the way in
    that its rows allow."""
    shapes = [box("shelf", (3.5364, 0.0), (5.2361, 0.9975), 0.0, 0.15)]
    reach = 0.380232 + 0.105  # a formation of one's ellipse plus a radius
    mates = {"r11": (3.879, 1.230, reach), "r8": (3.247, 0.853, reach), "r9": (3.010, 1.062, reach)}
    body = Body(((0.0, 0.0),), radius=0.105, margin=PLAN_MARGIN + 0.1)
    start, goal = (3.405, 1.308, 0.0), (3.8314, 0.8537, 0.0)
    r = Replanner(body, 0.0, goal, shapes)
    r.mates = frozenset(mates)
    job = r.begin(0.0, start, tuple(sorted((f"formation/{n}", c) for n, c in mates.items())))
    plan = plan_job(job).plan
    assert plan.reason == "" and plan.route[-1] == goal
    assert max(x for x, _y, _th in plan.route) > 4.2  # round the east teammate
    robots = plan_job(job._replace(circles=tuple(near for _c, near in job.mates))).plan
    assert robots.route[-1] == goal and max(x for x, _y, _th in robots.route) < 4.0  # between


@settings(max_examples=25, deadline=None)
@given(shelves=st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-2.0, 2.0), st.floats(0.2, 1.5),
                                  st.floats(0.2, 1.5), st.floats(-1.6, 1.6)), min_size=1, max_size=5),
       circles=st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-2.0, 2.0), st.floats(0.2, 0.6)),
                        max_size=3),
       goal_heading=st.floats(-3.1, 3.1))
def test_a_returned_route_keeps_the_footprint_clear_of_everything(shelves, circles, goal_heading):
    shapes = [box(f"b{k}", (x, y), (w, d), yaw, 0.15) for k, (x, y, w, d, yaw) in enumerate(shelves)]
    start, goal = (-5.5, 0.0, 0.0), (5.5, 0.5, goal_heading)
    plan = plan_footprint(start, goal, LINE, shapes, circles)
    if plan.reason:
        return  # no route is allowed (the shelves may close the way); a route must be clear
    for pose in _legs(start, plan.route):
        assert _clearance(LINE, pose, shapes, circles) > -1e-9


def test_still_things_count_after_three_seconds_and_static_circles_at_once():
    still = StillThings()
    things = [Thing("obstacle/pillar", 0.0, 0.0, 0.0, 0.5, static=True),
              Thing("obstacle/forklift", 3.0, 0.0, 0.0, 0.5)]
    assert [n for n, _c in still.update(0.0, things)] == ["obstacle/pillar"]
    assert [n for n, _c in still.update(2.9, things)] == ["obstacle/pillar"]
    assert [n for n, _c in still.update(3.0, things)] == ["obstacle/forklift", "obstacle/pillar"]
    moving = [things[0], things[1]._replace(speed=0.5)]
    # once counted still, a thing stays so until it has moved STILL.moved_m / 3 from where it stood
    assert [n for n, _c in still.update(3.1, moving)] == ["obstacle/forklift", "obstacle/pillar"]
    gone = [things[0], things[1]._replace(x=3.0 + STILL.moved_m / 3 + 0.01, speed=0.5)]
    assert [n for n, _c in still.update(3.3, gone)] == ["obstacle/pillar"]
    back = [things[0], things[1]._replace(x=3.2)]  # and counts again only 3 s after it stops
    assert [n for n, _c in still.update(3.4, back)] == ["obstacle/pillar"]
    assert [n for n, _c in still.update(6.4, back)] == ["obstacle/forklift", "obstacle/pillar"]


def test_a_parked_formation_whose_ellipse_twitches_stays_planned_around():
    """In a warehouse run a parked formation's speed passed STILL.speed now and then as its
    members settled; each time it left the planned-around set and came back 3 s later, and every
    formation planned again each time. Where it stands, a twitch changes nothing."""
    still = StillThings()
    parked = Thing("formation/b", 1.0, -5.0, 0.0, 1.4)
    seen = []
    for k in range(200):  # 20 s at 10 Hz, a 2 cm, 0.05 m/s twitch every 4 s from 3.5 s
        t = 0.1 * k
        twitch = k % 40 == 35
        th = parked._replace(x=1.0 + (0.02 if twitch else 0.0), speed=0.05 if twitch else 0.0)
        seen.append([n for n, _c in still.update(t, [th])])
    assert all(s == [] for s in seen[:30]) and all(s == ["formation/b"] for s in seen[30:])


def test_the_replanner_plans_again_off_route_and_without_progress_but_not_by_hand():
    r = Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0))
    route = ((5.0, 0.0),)
    assert r.check(3.0, (-4.0, 0.0, 0.0), route, 0, ()) is None
    assert r.check(3.0, (-4.0, 1.0, 0.0), route, 0, ()) == "off route"  # the line is 0.2 m wide
    assert r.check(9.0, (-4.0, 0.0, 0.0), route, 0, ()) == "no progress"
    assert r.check(3.0, (-4.0, 0.0, 0.0), route, 0, (("obstacle/f", (0.0, 0.0, 0.5)),)) == "things changed"
    by_hand = Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0), by_hand=True)
    assert by_hand.check(9.0, (-4.0, 3.0, 0.0), route, 0, ()) is None

def test_keeping_a_clear_route_plans_again_only_for_a_still_thing_across_its_rest():
    route = ((0.0, 0.0), (0.0, 5.0))  # north-east round a corner: east along y = 0, then north
    far = ("formation/p", (3.0, 3.0, 0.3))  # 3 m off both legs
    across = ("formation/q", (0.0, 3.0, 0.3))  # on the second leg, not yet walked
    behind = ("formation/s", (-4.5, 0.0, 0.3))  # on the first leg, walked past already
    plain = Replanner(LINE, 0.0, (0.0, 5.0, 0.0), [], start=(-5.0, 0.0))
    assert plain.check(3.0, (-3.0, 0.0, 0.0), route, 0, (far,)) == Reason.THINGS_CHANGED
    r = Replanner(LINE, 0.0, (0.0, 5.0, 0.0), [], start=(-5.0, 0.0))
    r.keep_if_clear = True
    assert r.check(3.0, (-3.0, 0.0, 0.0), route, 0, (far,)) is None
    assert r.planned == (far,)  # counted as planned round from now on
    assert r.check(3.0, (-3.0, 0.0, 0.0), route, 0, (far, behind)) is None
    assert r.check(3.0, (-3.0, 0.0, 0.0), route, 0, (far, across)) == Reason.THINGS_CHANGED
    moved_on = ("formation/p", (0.3, 2.0, 0.3))  # the far one moved onto the second leg
    assert r.check(3.0, (-3.0, 0.0, 0.0), route, 0, (moved_on,)) == Reason.THINGS_CHANGED



def test_a_formation_that_waits_for_traffic_too_long_plans_round_the_formations_in_its_way():
    """Two formations head-on in a one-lane aisle each creep: each is traffic to the other, which
    stops the progress clock; after PROGRESS.blocked_s without progress the plan goes round them."""
    r = Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0))
    route = ((5.0, 0.0),)
    assert r.check(0.0, (-4.0, 0.0, 0.0), route, 0, (), busy=True) is None
    assert r.check(9.0, (-4.0, 0.0, 0.0), route, 0, (), busy=True) is None  # waiting, not stuck
    assert r.check(PROGRESS.blocked_s, (-4.0, 0.0, 0.0), route, 0, (), busy=True) == Reason.BLOCKED
    seen = [Thing("formation/b", -2.5, 0.0, 0.03, 0.5), Thing("obstacle/forklift", -3.0, 0.5, 0.1, 0.45),
            Thing("formation/far", 4.0, 0.0, 0.2, 0.5), Thing("formation/parked", -3.0, -1.0, 0.0, 0.5)]
    extra = blockers((-4.0, 0.0, 0.0), LINE.rho, seen)
    assert extra == (("formation/b", (-2.5, 0.0, 0.5)),)  # moving, near, a formation
    job = r.begin(PROGRESS.blocked_s, (-4.0, 0.0, 0.0), (), extra)
    assert job.circles == ((-2.5, 0.0, 0.5),) and r.planned == ()  # planned round once, not kept
    assert r.finish(FootprintPlan((), "no route"), Reason.BLOCKED) is None  # keep the route: it may clear
    assert r.unreachable == ""
    assert r.check(PROGRESS.blocked_s + 3.0, (-4.0, 0.0, 0.0), route, 0, (), busy=True) is None  # clock anew


def test_a_detour_round_blockers_is_planned_again_once_they_have_left_the_way():
    """In a warehouse run c went round b, which was passing through the gap c needed, and came
    back only when b had parked. Once every formation the detour went round is off the
    way c was on (beyond its reach and the footprint's), c plans again without them."""
    r = Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0))
    route = ((5.0, 0.0),)
    assert r.check(0.0, (-4.0, 0.0, 0.0), route, 0, (), busy=True) is None
    assert r.check(PROGRESS.blocked_s, (-4.0, 0.0, 0.0), route, 0, (), busy=True) == Reason.BLOCKED
    b = Thing("formation/b", -2.5, 0.0, 0.03, 0.5)
    extra = blockers((-4.0, 0.0, 0.0), LINE.rho, [b])
    r.finish(plan_job(r.begin(PROGRESS.blocked_s, (-4.0, 0.0, 0.0), (), extra)), Reason.BLOCKED)
    detour = ((-4.0, 2.0), (5.0, 2.0), (5.0, 0.0))
    t = PROGRESS.blocked_s + PACE.every_s
    assert r.check(t, (-4.0, 1.0, 0.0), detour, 0, (), seen=[b]) is None  # b still on the way
    moved_along = b._replace(x=1.0, y=0.3)
    assert r.check(t, (-4.0, 1.0, 0.0), detour, 0, (), seen=[moved_along]) is None  # still on it
    gone = b._replace(x=1.0, y=-3.0)
    assert r.check(t, (-4.0, 1.0, 0.0), detour, 0, (), seen=[gone]) == Reason.WAY_CLEAR
    assert r.check(t, (-4.0, 1.0, 0.0), detour, 0, (), seen=[]) == Reason.WAY_CLEAR  # out of sight
    r.plan(t, (-4.0, 1.0, 0.0), (), Reason.WAY_CLEAR)  # without them: no detour to come back from
    assert r.check(t + PACE.every_s, (-4.0, 1.0, 0.0), route, 0, (), seen=[gone]) is None

def test_of_two_formations_blocked_by_each_other_the_later_name_goes_round():
    """a and b stand head-on, each blocked by the other: b (the later name) plans round a, a keeps
    its route for PROGRESS.blocked_s more, then goes round too (b may not be waiting for it at all)."""
    route = ((5.0, 0.0),)
    a, b = (Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0)) for _ in range(2))
    a.name, b.name = "a", "b"
    for r in (a, b):
        assert r.check(0.0, (-4.0, 0.0, 0.0), route, 0, (), busy=True) is None
        assert r.check(PROGRESS.blocked_s, (-4.0, 0.0, 0.0), route, 0, (), busy=True) == Reason.BLOCKED
    sees_b = (("formation/b", (-2.5, 0.0, 0.5)), ("obstacle/forklift", (-3.0, 0.5, 0.45)))
    assert a.waits_for(PROGRESS.blocked_s, sees_b)
    assert not a.waits_for(2.0 * PROGRESS.blocked_s, sees_b)  # no longer than PROGRESS.blocked_s more
    assert not b.waits_for(PROGRESS.blocked_s, (("formation/a", (-2.5, 0.0, 0.5)),))
    assert not a.waits_for(PROGRESS.blocked_s, ())
    by_hand = Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0), by_hand=True)
    by_hand.name = "a"
    assert not by_hand.waits_for(PROGRESS.blocked_s, sees_b)


def test_a_member_passes_a_waypoint_with_a_heading_only_once_the_formation_has_turned():
    f = Follower("a", (5.5, 0.0), (5.0, 0.0), ((0.0, 0.0), (5.0, 0.0)), (1.0, None))
    f.step(0.0, 0.05, heading=0.2)  # at the point, not turned yet: stays on it
    assert f.index == 0 and f.heading == 1.0
    f.step(0.0, 0.05, heading=0.9)
    assert f.index == 1 and f.heading is None
    g = Follower("a", (5.5, 0.0), (5.0, 0.0), ((0.0, 0.0), (5.0, 0.0)))
    g.step(0.0, 0.05, heading=0.2)  # no headings: passed on position alone, as before
    assert g.index == 1


def test_a_wide_formation_passes_a_turning_waypoint_only_once_its_outer_member_has_settled():
    # 0.09 rad from the heading: a pair 0.15 m from its centre to a member pivots at kp rho err
    # = 0.027 m/s and goes on; one 0.6 m out still swings at 0.108 m/s and finishes the turn
    # (route-head-on-aisle's rear member reversed when its formation went on at 0.15 rad)
    assert heading_tolerance(2.0, 0.15) == HEADING_TOLERANCE
    wide = heading_tolerance(2.0, 0.6)
    assert 2.0 * 0.6 * wide == pytest.approx(SETTLED_SPEED) and wide < 0.09
    for rho, passed in ((0.15, 1), (0.6, 0)):
        f = Follower("a", (5.5, 0.0), (5.0, 0.0), ((0.0, 0.0), (5.0, 0.0)), (1.0, None),
                     heading_tolerance(2.0, rho))
        f.step(0.0, 0.05, heading=0.91)
        assert f.index == passed
    assert heading_tolerance(0.0, 0.6) == HEADING_TOLERANCE  # no turn pull: the fixed tolerance
    assert heading_tolerance(2.0, None) == HEADING_TOLERANCE  # no rigid body (method thesis)
    assert SETTLED_SPEED == REVERSAL_SPEED  # the reversal counter's floor


def test_a_turning_waypoint_waits_for_a_drift_off_the_next_leg_to_settle():
    # route-give-way's hexagon turned within the tolerance while its centroid crept 0.035 m/s
    # north and pivoted at 0.035 m/s; the leg after the waypoint led east, and its outer
    # member's command went from 0.056 m/s north-west to 0.077 m/s south-east (a reversal)
    route = ((0.0, 0.0), (5.0, 0.0))
    f = Follower("a", (5.5, 0.0), (5.0, 0.0), route, (1.0, None))
    f.step(0.0, 0.05, heading=0.95, motion=(0.001, 0.035, 0.035))
    assert f.index == 0  # turned, still drifting across the next leg: stays on the waypoint
    f.step(0.0, 0.05, heading=0.95, motion=(0.001, 0.02, 0.026))
    assert f.index == 1  # every member slower than SETTLED_SPEED
    for along in ((0.1, 0.0, 0.03), (0.06, 0.08, 0.03)):  # along the next leg, 53 degrees off it
        g = Follower("a", (5.5, 0.0), (5.0, 0.0), route, (1.0, None))
        g.step(0.0, 0.05, heading=0.95, motion=along)
        assert g.index == 1  # moving on the way the next leg goes: nothing turns round
    h = Follower("a", (5.5, 0.0), (5.0, 0.0), route, (1.0, None))
    h.step(0.0, 0.05, heading=0.5, motion=(0.0, 0.0, 0.0))
    assert h.index == 0  # at rest but not turned: the heading still holds it
    assert motion_of(Ellipse(0.0, 0.0, 0.0, 1.0, 0.5, 0.03, -0.04, -0.1), 0.5) == (0.03, -0.04, 0.05)


def test_a_turning_waypoint_whose_next_heading_lies_back_the_other_way_waits_for_the_turn_to_settle():
    # route-head-on-aisle's pair turned at 0.067 m/s towards -1.178 rad, passed it at -1.104 for
    # the next waypoint's -0.785 (back the way it came) and its outer member reversed
    route = ((2.23, 0.99), (2.23, 0.99), (3.03, 1.79))
    spinning = (0.063, 0.007, 0.067)
    f = Follower("a", (3.0, 1.8), (3.03, 1.79), route, (-1.178, -0.785, -0.196), 0.083)
    f.step(2.16, 0.964, heading=-1.104, motion=spinning)
    assert f.index == 0  # within the tolerance, still turning: the next turn is back
    f.step(2.16, 0.964, heading=-1.17, motion=(0.01, 0.0, 0.03))
    assert f.index == 1  # settled: on to -0.785 (and not past it: -1.17 is 0.6 rad short)
    g = Follower("a", (3.0, 1.8), (3.03, 1.79), route, (-1.178, -1.5, -0.196), 0.083)
    g.step(2.16, 0.964, heading=-1.104, motion=spinning)
    assert g.index == 1  # the next heading lies on the way it turns: no need to settle


def _dead_end():
    """A 2 m wide corridor along x from x = -1 to 6 (walls at y = +-1), closed at x = 6, that
    opens at x = -1 into a hall 10 m wide (walls at x = -7, y = +-5)."""
    walls = [((-7, -5), (-7, 5)), ((-7, 5), (-1, 5)), ((-7, -5), (-1, -5)), ((-1, 5), (-1, 1)),
             ((-1, -5), (-1, -1)), ((-1, 1), (6, 1)), ((-1, -1), (6, -1)), ((6, -1), (6, 1))]
    return [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(walls)]


def test_a_formation_giving_way_backs_out_of_a_dead_end_to_the_nearest_place_off_the_way():
    """The other formation's way runs down the corridor's axis and on across the hall to
    (-6, 0): the nearest place off it (by 1.5 m) is in the hall beside the corridor's mouth,
    and the footprint's route there is clear all along."""
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    way = [(5.0, 0.0), (-6.0, 0.0)]
    start = (2.0, 0.0, math.pi)
    plan = plan_aside(start, square, _dead_end(), (), way, 1.5)
    assert plan.reason == "", plan
    x, y, _th = plan.route[-1]
    assert abs(y) >= 1.5 - 1e-9 and -7.0 < x < -1.0  # out of the corridor, off the way
    assert x > -3.5  # the nearest such place: just out of the corridor's mouth
    for pose in _legs(start, plan.route):
        assert _clearance(square, pose, _dead_end(), ()) > 0.0


@pytest.mark.slow  # seconds in-process: left out of `make check`
def test_giving_way_where_no_place_is_off_the_way_says_so():
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    plan = plan_aside((2.0, 0.0, 0.0), square, _dead_end(), (), [(5.0, 0.0), (-6.0, 0.0)], 6.0)
    assert plan.route == () and "no place" in plan.reason


def test_a_formation_already_off_the_way_stays_where_it_is():
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    start = (-4.0, 3.0, 0.0)
    plan = plan_aside(start, square, _dead_end(), (), [(5.0, 0.0), (-6.0, 0.0)], 1.5)
    assert plan.route == (start,)


def test_two_formations_in_each_others_only_way_the_later_name_gives_way_and_then_goes_on():
    """A square deep in the dead end (goal out in the hall) and another at its mouth (goal deep
    inside): each plans round the other as parked and finds no route; the plan without the
    parked formations names the one in the way. The later name stands aside, off the earlier
    one's way, once that one reports no route too; the earlier one never does; after GIVING.most_s,
    or once the other reports it has arrived, the one aside plans for its goal again."""
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    walls = _dead_end()
    inner = Replanner(square, 0.0, (-5.0, 0.0, 0.0), walls, start=(4.0, 0.0))
    outer = Replanner(square, 0.0, (4.5, 0.0, 0.0), walls, start=(0.5, 0.0))
    inner.name, outer.name = "a", "b"
    inner_at, outer_at = (4.0, 0.0, 0.0), (0.5, 0.0, 0.0)
    # each sees the other parked: a circle of its ellipse's semi-major axis and a robot radius
    sees_outer = (("formation/b", (0.5, 0.0, 0.53)),)
    sees_inner = (("formation/a", (4.0, 0.0, 0.53)),)
    held = inner.finish(plan_job(inner.begin(0.0, inner_at, sees_outer)), Reason.START)
    assert held is not None and held.route == () and inner.blocked_by == ("b",)
    assert "formation b" in inner.unreachable
    outer.finish(plan_job(outer.begin(0.0, outer_at, sees_inner)), Reason.START)
    assert outer.blocked_by == ("a",)
    reports = {"a": Other(UNREACHABLE, 4.0, 0.0, -5.0, 0.0, 0.42),
               "b": Other(UNREACHABLE, 0.5, 0.0, 4.5, 0.0, 0.42)}
    assert inner.check(6.0, inner_at, ((-5.0, 0.0),), 0, sees_outer, others=reports) != Reason.GIVE_WAY
    assert outer.check(6.0, outer_at, ((4.5, 0.0),), 0, sees_inner, others=reports) == Reason.GIVE_WAY
    assert outer.give_way(6.0, reports) == "a"
    job = outer.begin_give_way(6.0, outer_at, sees_inner, "a", reports["a"], 0.105)
    upd = outer.finish_give_way(give_way_job(job), "a")
    assert upd is not None and upd.why == Reason.GIVE_WAY and outer.giving_way == "a"
    x, y = upd.route[-1]
    assert abs(y) > 0.42 + square.rho + 0.105 and x < -1.0  # out in the hall, off a's way
    assert outer.check(20.0, (x, y, 0.0), upd.route, len(upd.route) - 1, (), others=reports) is None
    arrived = {**reports, "a": Other(REACHED, -5.0, 0.0, -5.0, 0.0, 0.42)}
    assert outer.check(30.0, (x, y, 0.0), upd.route, len(upd.route) - 1, (), others=arrived) == "given way"
    end = len(upd.route) - 1
    assert outer.check(6.0 + GIVING.most_s - 1.0, (x, y, 0.0), upd.route, end, (), others=reports) is None
    assert outer.check(6.0 + GIVING.most_s, (x, y, 0.0), upd.route, end, (), others=reports) == "given way"


def test_a_formation_boxed_in_behind_a_holding_one_is_given_way():
    """A square deep in the dead end has a route out, but the holding square at the mouth stands
    in it and nothing shoves that one aside (each formation keeps its ellipse off the other's
    members): its blocked plan round the one in its way finds nothing, so it keeps its route and
    is boxed in (reported stalled). The holding one, with no route of its own while the first
    stands in its way, gives way to it as to one with no route; once the first makes progress
    it is no longer boxed in."""
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    walls = _dead_end()
    inner = Replanner(square, 0.0, (-5.0, 0.0, 0.0), walls, start=(4.0, 0.0))
    inner.name = "a"
    route = ((0.5, 0.0), (-5.0, 0.0))
    extra = (("formation/b", (0.5, 0.0, 0.53)),)
    assert inner.finish(plan_job(inner.begin(20.0, (3.0, 0.0, 0.0), (), extra)), Reason.BLOCKED) is None
    assert inner.boxed_in and not inner.unreachable  # it keeps its route: the way may clear
    outer = Replanner(square, 0.0, (4.5, 0.0, 0.0), walls, start=(0.5, 0.0))
    outer.name, outer.unreachable, outer.blocked_by = "b", "no way", ("a",)
    boxed = {"a": Other(STALLED, 3.0, 0.0, -5.0, 0.0, 0.42)}
    assert outer.give_way(26.0, boxed) == "a"
    # the first one moves on (1 m along its route): no longer boxed in
    assert inner.check(23.0, (2.0, 0.0, 0.0), route, 0, ()) is None
    assert not inner.boxed_in


def test_a_formation_not_in_the_others_way_or_whose_other_has_a_route_does_not_give_way():
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    r = Replanner(square, 0.0, (4.5, 0.0, 0.0), _dead_end(), start=(0.5, 0.0))
    r.name, r.unreachable, r.blocked_by = "b", "no way", ("a",)
    moving = {"a": Other("moving", 4.0, 0.0, 5.0, 0.0, 0.42)}
    assert r.give_way(6.0, moving) == ""  # a has a route: it will move on
    assert r.give_way(6.0, {}) == ""  # a not heard (or its report too old)
    off = GiveWayJob((-4.0, 3.0, 0.0), square, tuple(_dead_end()), (), Other(
        UNREACHABLE, 4.0, 0.0, 5.0, 0.0, 0.42), (), 0.105)
    assert give_way_job(off).reason == "not in the other formation's way"


def test_a_formation_parked_in_the_only_way_stands_aside_for_the_one_with_no_route():
    """In warehouse draws a square parked at (or, kept short by the
    other, within 1 m of) its goal at the dead end's mouth stands in the only way of one deep
    inside that reports no route. Nothing asked a formation with a route to move; now one
    parked near its goal stands aside for any that reports no route where it stands in that
    one's way, and plans for its goal again once that one has arrived. Still moving, or parked
    off the other's way, it does not."""
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    walls = _dead_end()
    parked = Replanner(square, 0.0, (0.5, 0.0, 0.0), walls, start=(-5.0, 0.0))
    parked.name = "b"
    at = (0.5 + 0.8, 0.0, 0.0)  # 0.8 m short of its goal: near enough
    assert parked.parked(at) and not parked.parked((-1.0, 0.0, 0.0))
    stuck = {"a": Other(UNREACHABLE, 4.0, 0.0, -5.0, 0.0, 0.42)}
    assert parked.give_way(6.0, stuck) == ""  # no pose: the old rule (it has a route)
    assert parked.check(6.0, at, ((0.5, 0.0),), 0, (), others=stuck) == Reason.GIVE_WAY
    assert parked.give_way(6.0, stuck, at) == "a"
    job = parked.begin_give_way(6.0, at, (), "a", stuck["a"], 0.105)
    upd = parked.finish_give_way(give_way_job(job), "a")
    assert upd is not None and parked.giving_way == "a"
    x, y = upd.route[-1]
    assert abs(y) > 0.42 + square.rho + 0.105  # out in the hall, off a's way
    arrived = {"a": Other(REACHED, -5.0, 0.0, -5.0, 0.0, 0.42)}
    assert parked.check(30.0, (x, y, 0.0), upd.route, len(upd.route) - 1, (),
                        others=arrived) == "given way"
    # moving on its route (far from its goal), or someone with a route: no standing aside
    going = Replanner(square, 0.0, (0.5, 0.0, 0.0), walls, start=(-5.0, 0.0))
    going.name = "b"
    assert going.give_way(6.0, stuck, (-3.0, 0.0, 0.0)) == ""
    assert going.give_way(6.0, {"a": Other("moving", 4.0, 0.0, -5.0, 0.0, 0.42)}, at) == ""
    # parked out of the way: the job finds it is not in the way, and nothing moves
    off = GiveWayJob((-4.0, 3.0, 0.0), square, tuple(walls), (), stuck["a"], (), 0.105)
    assert give_way_job(off).reason == "not in the other formation's way"


def _one_lane_aisle():
    """A one-lane aisle (2 m wide) along x from -5 to 6 between two halls, all inside walls
    at x = -10 and 11, y = +-5."""
    walls = [((-10, -5), (11, -5)), ((-10, 5), (11, 5)), ((-10, -5), (-10, 5)), ((11, -5), (11, 5)),
             ((-5, 1), (6, 1)), ((-5, -1), (6, -1)), ((-5, 1), (-5, 5)), ((-5, -1), (-5, -5)),
             ((6, 1), (6, 5)), ((6, -1), (6, -5))]
    return [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(walls)]


def test_a_formation_stuck_on_its_way_stands_aside_for_the_one_with_no_route_and_not_through_it():
    """A triangle 1.02 m from its goal (just further than GIVING.parked_m), on which a pentagon
    with no route stood, waited for it in a one-lane aisle for ever. A formation that has made
    no progress for PROGRESS.blocked_s stands aside as a parked one does; and
    it plans its way aside round the other where that one stands, still or not (the pentagon
    crept as it held, so it was no still thing, and the triangle was sent west through it)."""
    square = Body(((0.3, 0.3), (-0.3, 0.3), (-0.3, -0.3), (0.3, -0.3)), radius=0.105, margin=0.05)
    walls = _one_lane_aisle()
    giver = Replanner(square, 0.0, (-8.0, 3.0, 0.0), walls, start=(-1.5, 0.0))
    giver.name = "b"
    at = (-1.5, 0.0, 0.0)
    assert not giver.parked(at)
    other = {"a": Other(UNREACHABLE, -3.0, 0.0, 9.0, 0.0, 0.42)}  # in the aisle, bound east
    assert giver.give_way(PROGRESS.blocked_s - 1.0, other, at) == ""  # not stuck yet
    assert giver.check(PROGRESS.blocked_s - 1.0, at, ((-8.0, 3.0),), 0, ()) is None  # progress: the first
    assert giver.give_way(2.0 * PROGRESS.blocked_s - 2.0, other, at) == ""
    assert giver.stuck(2.0 * PROGRESS.blocked_s - 1.0)
    assert giver.give_way(2.0 * PROGRESS.blocked_s - 1.0, other, at) == "a"
    # the other is in no list of still things (it creeps), and is planned round all the same
    job = giver.begin_give_way(2.0 * PROGRESS.blocked_s - 1.0, at, (), "a", other["a"], 0.105)
    assert job.circles == ((-3.0, 0.0, pytest.approx(0.42 + 0.105)),)
    upd = giver.finish_give_way(give_way_job(job), "a")
    assert upd is not None and giver.giving_way == "a"
    x, y = upd.route[-1]
    assert x > 6.0 and abs(y) > 0.42 + square.rho + 0.105  # out of the aisle's east end, aside
    assert all(px > -1.6 for px, _py in upd.route)  # never west, through the other
    # a route given by hand is never moved
    by_hand = Replanner(square, 0.0, (-8.0, 3.0, 0.0), walls, start=(-1.5, 0.0), by_hand=True)
    by_hand.name = "b"
    assert not by_hand.stuck(100.0) and by_hand.give_way(100.0, other, at) == ""


def _two_aisles(closed_north: bool = False):
    """A hall 20 m x 4 m (walls at x = +-10, y = +-2) split along x by a shelf row (y -0.45 ..
    0.45, x -7 .. 7); ``closed_north``: a wall shuts the north aisle at x = 7 (a dead end)."""
    walls = [((-10, -2), (10, -2)), ((10, -2), (10, 2)), ((10, 2), (-10, 2)), ((-10, 2), (-10, -2))]
    out = [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(walls)]
    out.append(box("row", (0.0, 0.0), (14.0, 0.9), 0.0, 0.15))
    if closed_north:
        out.append(segment("plug", (7.0, 0.0), (7.0, 2.0), 0.15))
    return out


def test_a_route_head_on_into_a_forklifts_way_goes_round_it_where_there_is_a_way():
    """In a warehouse draw a hexagon sent down the middle aisle head-on into a forklift (no
    room beside it) stood, then backed away from it for 100 s. A route that meets a moving
    thing's next LANES.ahead_s head-on goes round where that thing drives, where another way exists."""
    shapes = _two_aisles()
    start, goal = (-8.5, -1.2, 0.0), (8.5, -1.2, 0.0)  # the south aisle's robots: y -1.85 .. -0.6
    forklift = Thing("obstacle/forklift", 5.0, -1.225, 0.1, 0.6, False, -0.1, 0.0)  # fills it
    moving = lanes([forklift, Thing("formation/b", 0.0, 1.0, 0.2, 0.5, False, 0.2, 0.0),
                    Thing("obstacle/parked", 0.0, 1.0, 0.0, 0.45)])
    assert moving == ((5.0, -1.225, -0.1, 0.0, 0.6),)  # neither a formation nor a still thing
    plain = plan_job(PlanJob(start, goal, LINE, tuple(shapes), ()))
    assert max(p[1] for p in plain.plan.route) < 0.0  # down the south aisle
    assert oncoming(start, plain.plan.route, LINE.rho, moving[0])
    round_ = plan_job(PlanJob(start, goal, LINE, tuple(shapes), (), (), moving))
    assert round_.plan.route and max(p[1] for p in round_.plan.route) > 0.45  # the north aisle
    assert not oncoming(start, round_.plan.route, LINE.rho, moving[0])
    ahead = (5.0, -1.225, 0.1, 0.0, 0.6)  # driving the same way: followed, not met
    assert not oncoming(start, plain.plan.route, LINE.rho, ahead)
    same = plan_job(PlanJob(start, goal, LINE, tuple(shapes), (), (), (ahead,)))
    assert same.plan.route == plain.plan.route
    dead_end = tuple(_two_aisles(closed_north=True))  # no other way: the way, the barriers wait
    kept = plan_job(PlanJob(start, goal, LINE, dead_end, (), (), moving))
    assert kept.plan.route and max(p[1] for p in kept.plan.route) < 0.0 and not kept.plan.reason


def test_a_forklift_past_the_leg_before_the_formation_can_get_there_is_not_oncoming():
    """In a warehouse draw a forklift driving south out of the aisle a hexagon's route went
    north up, already past the aisle's mouth, sent it 40 m round the hall the other way. Its
    way counts from the earliest the formation can be on each leg (at its top speed)."""
    start, route = (0.0, 0.0, 0.0), ((10.0, 0.0, 0.0), (10.0, 10.0, 0.0))  # 10 m east, then north
    leaving = (10.5, 3.0, 0.0, -0.15, 0.45)  # at the aisle's mouth, driving south out of it
    assert oncoming(start, route, 0.6, leaving)  # timeless: its way crosses the leg's start
    assert not oncoming(start, route, 0.6, leaving, speed=0.22)  # gone 45 s before it gets there
    coming = (10.5, 12.0, 0.0, -0.15, 0.45)  # still up the aisle when the formation turns into it
    assert oncoming(start, route, 0.6, coming, speed=0.22)
    late = (10.5, 30.0, 0.0, -0.15, 0.45)  # reaches the aisle only after LANES.ahead_s
    assert not oncoming(start, route, 0.6, late, speed=0.22)


def test_a_lane_is_circles_along_the_next_lane_s_less_those_the_start_reaches():
    lane = (5.0, 0.0, -0.1, 0.0, 0.4)
    far = lane_circles((-10.0, 0.0, 0.0), 0.5, lane)
    assert far[0] == (5.0, 0.0, 0.4) and far[-1][0] == pytest.approx(5.0 - 0.1 * LANES.ahead_s)
    assert all(a[0] - b[0] <= 0.2 + 1e-9 for a, b in zip(far[:-1], far[1:], strict=True))  # Ds / 2 apart
    near = lane_circles((1.0, 0.0, 0.0), 0.5, lane)
    assert near and all(math.dist((1.0, 0.0), c[:2]) > 0.4 + 0.5 for c in near)
    assert len(near) < len(far)


def test_a_robot_alone_is_planned_on_one_heading_and_its_no_is_quick():
    alone = Body(((0.0, 0.0),), radius=0.105)
    pair = Body(((0.0, 0.3), (0.0, -0.3)), radius=0.105)
    assert alone.turn_free and alone.headings(32) == 1
    assert not pair.turn_free and pair.headings(32) == 32
    assert not Body(((0.0, 0.0),), load=((0.4, 0.3), (-0.4, 0.3), (-0.4, -0.3)),
                    radius=0.105).turn_free
    # round a shelf: a route that keeps the margin, on the one heading it starts with
    shelf = box("shelf", (0.0, 0.0), (2.0, 0.8), 0.0, 0.15)
    plan = plan_footprint((-2.0, 0.0, 0.0), (2.0, 0.0, 0.0), alone, [shelf])
    assert plan.route and plan.route[-1] == (2.0, 0.0, 0.0)
    assert all(th == 0.0 for _x, _y, th in plan.route)
    # a goal walled in: "no way" once the few poses it can reach are spent, not at the limit
    room = [segment(f"w{k}", a, b, 0.15) for k, (a, b) in enumerate(
        [((1.5, -0.5), (2.5, -0.5)), ((2.5, -0.5), (2.5, 0.5)), ((2.5, 0.5), (1.5, 0.5)),
         ((1.5, 0.5), (1.5, -0.5))])]
    shut = plan_footprint((-2.0, 0.0, 0.0), (2.0, 0.0, 0.0), alone, [shelf, *room])
    assert not shut.route and shut.expanded < SEARCH.max_expansions

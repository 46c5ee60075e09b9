"""agent.load_rows: each member's own rows for its formation's load."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agent import double_integrator as di
from agent import load_rows, unicycle
from agent.barriers import Obstacle, Partner
from agent.body import footprint_of
from agent.control import Controller, ControlParams, StepInput
from geometry.rigid import rigid_fit
from geometry.shapes import box

coord = st.floats(-2.0, 2.0)
speed = st.floats(-0.3, 0.3)


def _start_and_now(draw_pts, turn, shift):
    start = [(x, y) for x, y in draw_pts]
    cx = sum(x for x, _ in start) / len(start)
    cy = sum(y for _, y in start) / len(start)
    offs = [(x - cx, y - cy) for x, y in start]
    c, s = math.cos(turn), math.sin(turn)
    now = [(c * x - s * y + shift[0], s * x + c * y + shift[1]) for x, y in offs]
    return offs, now


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=2, max_size=6), st.floats(-3.0, 3.0),
       st.tuples(coord, coord), st.lists(st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)),
                                         min_size=6, max_size=6))
def test_the_load_is_placed_where_the_safety_monitor_places_it(pts, turn, shift, jitter):
    offs, now = _start_and_now(pts, turn, shift)
    assume(sum(x * x + y * y for x, y in offs) > 0.05)
    now = [(x + j[0], y + j[1]) for (x, y), j in zip(now, jitter, strict=False)]
    outline = [(0.5, 0.2), (-0.4, 0.3), (0.1, -0.6)]
    placed = load_rows.place_load(offs, outline, now)
    assert placed is not None
    want = rigid_fit(offs, now).apply_all(outline)
    for p, q in zip(placed.outline, want, strict=True):
        assert p == pytest.approx(q, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=2, max_size=5), st.floats(-3.0, 3.0),
       st.lists(st.tuples(speed, speed), min_size=5, max_size=5), st.tuples(coord, coord),
       st.floats(0.0, 2 * math.pi))
def test_the_gradients_are_the_load_points_velocity_under_the_fit(pts, turn, vel, p0, mdir):
    """(L.1): g_k . u_k summed is d/dt (m . P) for P the load point the fit carries."""
    offs, now = _start_and_now(pts, turn, (0.3, -0.2))
    assume(min(math.hypot(*o) for o in offs) > 0.1)
    assume(min(math.dist(a, b) for i, a in enumerate(offs) for b in offs[i + 1:]) > 0.1)
    vel = vel[:len(now)]
    placed = load_rows.place_load(offs, [p0], now)
    assert placed is not None
    m = (math.cos(mdir), math.sin(mdir))
    g = load_rows.gradients(placed, placed.outline[0], m, None)
    rate = sum(a[0] * v[0] + a[1] * v[1] for a, v in zip(g, vel, strict=True))
    dt = 1e-6
    later = [(x + dt * v[0], y + dt * v[1]) for (x, y), v in zip(now, vel, strict=True)]
    moved = load_rows.place_load(offs, [p0], later)
    assert moved is not None
    fd = (m[0] * (moved.outline[0][0] - placed.outline[0][0])
          + m[1] * (moved.outline[0][1] - placed.outline[0][1])) / dt
    assert rate == pytest.approx(fd, abs=1e-4)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(speed, speed), min_size=2, max_size=5),
       st.lists(st.tuples(speed, speed), min_size=5, max_size=5),
       st.lists(st.tuples(speed, speed), min_size=5, max_size=5),
       st.floats(-0.5, 0.5), st.floats(-0.2, 0.2))
def test_commands_that_meet_every_members_row_meet_the_loads_condition(g, v, du, h, q_term):
    """(L.2): whatever commands the members return together, each inside its own row, the
    load's barrier condition sum g_k . u_k >= -gamma h - q_term holds."""
    n = len(g)
    assume(all(math.hypot(*a) > 1e-3 for a in g))
    v, du = v[:n], du[:n]
    gamma = 1.0
    hdot = q_term + sum(a[0] * w[0] + a[1] * w[1] for a, w in zip(g, v, strict=True))
    u = []
    for k in range(n):  # project each member's try onto its own row
        row = load_rows.share_row(g, v[k], k, h, hdot, gamma)
        assert row is not None
        ux, uy = v[k][0] + du[k][0], v[k][1] + du[k][1]
        ax, ay, b = row
        over = ax * ux + ay * uy - b
        if over > 0:
            ux, uy = ux - over * ax, uy - over * ay
        u.append((ux, uy))
    total = sum(a[0] * w[0] + a[1] * w[1] for a, w in zip(g, u, strict=True))
    assert total >= -gamma * h - q_term - 1e-9


def _pair_step(shapes, obstacles, goal_y):
    """One tick of member 0 of a pair 1 m apart along x, both still, driven to +y."""
    p = ControlParams()
    fp = footprint_of([(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0), (1.0, 0.0)],
                      [(0.0, goal_y), (1.0, goal_y)], 0, [(0.0, 0.0), (1.0, 0.0)], False)
    return Controller(p).step(StepInput((0.0, 0.0, 0.0), (0.0, goal_y), obstacles=obstacles,
                                        shapes=shapes, partners=[Partner(1.0, 0.0, 0.0, 0.0)],
                                        footprint=fp))


def test_a_member_does_not_carry_the_load_onto_a_shelf_corner_between_it_and_its_partner():
    """A thin post whose corners sit 4.5 cm above the middle of the pair's load (0.5 m from
    each robot, beyond their own safe distance): a member driven towards it closes on it no
    faster than the load's barrier allows (gamma h, h = 4.5 cm less LOAD_CLEAR, its share with
    its still partner), and the same member with the post 0.5 m away goes on at full speed."""
    post = box("post", (0.5, 0.07), (0.05, 0.05), 0.0, 0.2)
    near = _pair_step([post], [], 1.0)
    assert 0.0 <= near.uy <= 0.045 - load_rows.LOAD_CLEAR + 1e-6
    far = box("post", (0.5, 0.55), (0.05, 0.05), 0.0, 0.2)
    free = _pair_step([far], [], 1.0)
    assert free.uy > 0.15
    assert free.h_obstacle > near.h_obstacle


def test_a_circle_coming_at_the_load_pushes_its_members_away():
    """A circle (physical radius 0.1 m) 0.14 m from the middle of the pair's load, coming at it
    at 0.2 m/s: each member backs away, though the circle is 0.5 m from either body."""
    coming = Obstacle(0.5, 0.14 + 0.1, 0.0, -0.2, 0.1 + ControlParams().radius)
    res = _pair_step([], [coming], 1.0)
    assert res.uy < -0.05


def test_a_double_integrator_brakes_before_its_load_meets_a_shelf_corner():
    """The pair of double integrators moving at 0.2 m/s towards the post 10 cm above their
    load's middle: each member's load row (a HOCBF) brakes it, though its own body is 0.5 m
    from the post; with the post far away it keeps its speed."""
    p = ControlParams(double_integrator=True, max_accel=1.0)
    fp = footprint_of([(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0), (1.0, 0.0)],
                      [(0.0, 1.0), (1.0, 1.0)], 0, [(0.0, 0.0), (1.0, 0.0)], False)

    def step(post_y):
        post = box("post", (0.5, post_y), (0.05, 0.05), 0.0, 0.2)
        return Controller(p).step(StepInput((0.0, 0.0, 0.0), (0.0, 5.0), shapes=[post],
                                            partners=[Partner(1.0, 0.0, 0.0, 0.2)],
                                            last_u=(0.0, 0.2), footprint=fp))

    assert step(0.125).ay < -0.2
    assert step(2.0).ay >= 0.0


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=2, max_size=4), st.floats(-3.0, 3.0),
       st.lists(st.tuples(speed, speed), min_size=4, max_size=4),
       st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)), min_size=1, max_size=4),
       st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), speed, speed), max_size=3),
       st.booleans(), st.booleans())
def test_culling_leaves_out_only_rows_that_cannot_be_active(pts, turn, vel, posts, circles,
                                                             unicycle, declared):
    """load_rows' bounds (by the bounding circle, then by h and h') drop no row that the QP
    could meet: the same rows as every barrier worked out and filtered by b < reach."""
    offs, now = _start_and_now(pts, turn, (0.1, 0.2))
    assume(min(math.dist(a, b) for i, a in enumerate(offs) for b in offs[i + 1:]) > 0.1)
    n = len(now)
    outline = [(-0.8, -0.5), (0.8, -0.5), (0.8, 0.5), (-0.8, 0.5)]
    placed = load_rows.place_load(offs, outline, now)
    assume(placed is not None)
    heads = [0.3 * k for k in range(n)] if unicycle else None
    load = load_rows.MemberLoad(placed, 0, vel[:n], heads, declared)
    shapes = [box(f"s{k}", p, (0.4, 0.3), 0.2 * k, 0.2) for k, p in enumerate(posts)]
    obstacles = [Obstacle(x, y, vx, vy, 0.3) for x, y, vx, vy in circles]
    reach = 0.22
    _, got = load_rows.load_rows(load, obstacles, shapes, 0.1, 0.01, 1.0, reach)
    _, feats = load_rows.features(load, obstacles, shapes, 0.1, 0.01, lambda *a: False)
    want = [r for f in feats
            if (r := load_rows.share_row(f.g, vel[0], 0, f.h, f.hdot, 1.0)) is not None
            and r[2] < reach]
    assert sorted(got) == sorted(want)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=3, max_size=4), st.floats(-3.0, 3.0),
       st.lists(st.tuples(speed, speed), min_size=4, max_size=4),
       st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)), min_size=1, max_size=4),
       st.booleans())
def test_members_sharing_one_memo_get_the_rows_each_finds_alone(pts, turn, vel, posts, unicycle):
    """LoadMemo finds the load's barriers once with the fastest member's test; every member,
    each with its own speed, selects exactly the rows and h it finds with a fresh memo."""
    offs, now = _start_and_now(pts, turn, (0.1, 0.2))
    assume(min(math.dist(a, b) for i, a in enumerate(offs) for b in offs[i + 1:]) > 0.1)
    n = len(now)
    placed = load_rows.place_load(offs, [(-0.8, -0.5), (0.8, -0.5), (0.8, 0.5), (-0.8, 0.5)], now)
    assume(placed is not None)
    heads = [0.3 * k for k in range(n)] if unicycle else None
    shapes = [box(f"s{k}", p, (0.4, 0.3), 0.2 * k, 0.2) for k, p in enumerate(posts)]
    obstacles = [Obstacle(1.0, -1.0, 0.1, 0.0, 0.3)]
    shared = load_rows.LoadMemo()
    for member in range(n):
        load = load_rows.MemberLoad(placed, member, vel[:n], heads, True)
        got = load_rows.load_rows(load, obstacles, shapes, 0.1, 0.01, 0.8, 0.22, shared)
        alone = load_rows.load_rows(load, obstacles, shapes, 0.1, 0.01, 0.8, 0.22,
                                    load_rows.LoadMemo())
        assert got == alone


def _unculled(load, obstacles, shapes, radius, clear, gamma, reach):
    """load_rows worked out without its check by the fit alone (:func:`agent.load_rows.idle`):
    every candidate found by the loosest member's test, then this member's selected (a
    unicycle member's at its floored rate, :func:`agent.unicycle.member_gamma`)."""
    if load.headings is not None:
        gamma = unicycle.member_gamma(gamma)
    v = load.velocities[load.member]
    floor = reach + math.hypot(v[0], v[1])
    loose = reach + max(math.hypot(u[0], u[1]) for u in load.velocities)
    found = load_rows.candidates(load, obstacles, shapes, radius, clear,
                                 lambda h, hdot, s, _v: gamma * h + hdot >= s * loose)
    hmin, feats = load_rows.select_linear(
        load, found, gamma, floor,
        lambda c: load_rows.gradients(load.placed, c.p, c.m, load.headings))
    rows = [r for f in feats
            if (r := load_rows.share_row(f.g, v, load.member, f.h, f.hdot, gamma)) is not None
            and r[2] < reach]
    return hmin, rows


def _loads(offs, outline, now, member, vel, heads, declared):
    """The same load placed at once and placed only when asked for (as member_load makes it)."""
    placed = load_rows.place_load(offs, outline, now)
    fit = load_rows.fit_load(offs, load_rows.outline_reach(outline), now)
    assert (placed is None) == (fit is None)
    if placed is None:
        return None
    n = len(now)
    eager = load_rows.MemberLoad(placed, member, vel[:n], heads, declared)
    lazy = load_rows.MemberLoad(lambda: load_rows.place_load(offs, outline, now), member,
                                vel[:n], heads, declared, fit)
    return eager, lazy


far = st.floats(-2000.0, 2000.0)
near = st.floats(-4.0, 4.0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=2, max_size=4), st.floats(-3.0, 3.0),
       st.tuples(far, far), st.lists(st.tuples(coord, coord), min_size=3, max_size=5),
       st.lists(st.tuples(speed, speed), min_size=4, max_size=4),
       st.lists(st.tuples(near, near), max_size=3),
       st.lists(st.tuples(near, near, speed, speed, st.floats(0.0, 0.6)), max_size=3),
       st.tuples(st.integers(0, 3), st.floats(0.0, 3.0), st.floats(0.0, 0.4), st.booleans(),
                 st.booleans()))
def test_rows_found_by_the_fit_alone_are_the_rows_of_the_placed_load(
        pts, turn, shift, outline, vel, posts, circles, knobs):
    """The check by the fit alone (its bounds of the placed radius and spread) leaves the rows
    and the smallest h exactly as without it, near shelves and circles and far from them, at
    any distance from the origin; the load is placed only where the check cannot rule it out,
    and the double integrators' rows (which place it) are those of the load placed at once."""
    member, gamma, reach, unicycle, declared = knobs
    offs, now = _start_and_now(pts, turn, shift)
    assume(member < len(now))
    heads = [0.3 * k for k in range(len(now))] if unicycle else None
    loads = _loads(offs, outline, now, member, vel, heads, declared)
    assume(loads is not None)
    eager, lazy = loads
    cx, cy = now[0]  # the things near the load, wherever it is
    shapes = [box(f"s{k}", (cx + x, cy + y), (0.4, 0.3), 0.2 * k, 0.2)
              for k, (x, y) in enumerate(posts)]
    obstacles = [Obstacle(cx + x, cy + y, vx, vy, ds) for x, y, vx, vy, ds in circles]
    want = _unculled(eager, obstacles, shapes, 0.1, 0.01, gamma, reach)
    assert load_rows.load_rows(lazy, obstacles, shapes, 0.1, 0.01, gamma, reach,
                               load_rows.LoadMemo()) == want
    assert load_rows.load_rows(eager, obstacles, shapes, 0.1, 0.01, gamma, reach,
                               load_rows.LoadMemo()) == want
    cp = ControlParams(max_speed=0.22, period=0.05, double_integrator=True, max_accel=0.5)
    assert di.load_rows_of(cp, lazy, obstacles, shapes) == di.load_rows_of(cp, eager, obstacles,
                                                                          shapes)


def test_a_load_far_from_everything_is_never_placed():
    """Away from every shelf and circle load_rows rules every barrier out by the fit alone:
    no rows, no smallest h, and the outline is not placed."""
    offs = [(-0.5, 0.0), (0.5, 0.0)]
    now = [(-0.5, 0.0), (0.5, 0.0)]
    outline = [(-0.6, -0.2), (0.6, -0.2), (0.6, 0.2), (-0.6, 0.2)]
    fit = load_rows.fit_load(offs, load_rows.outline_reach(outline), now)
    assert fit is not None

    def place():
        raise AssertionError("placed")

    load = load_rows.MemberLoad(place, 0, [(0.1, 0.0), (0.1, 0.0)], None, True, fit)
    far_box = [box("s", (9.0, 0.0), (0.4, 0.3), 0.0, 0.2)]
    assert load_rows.load_rows(load, [Obstacle(0.0, 9.0, 0.0, 0.0, 0.3)], far_box, 0.1, 0.01,
                               1.0, 0.22) == (math.inf, [])
    with pytest.raises(AssertionError, match="placed"):  # near: it is placed
        load_rows.load_rows(load, [Obstacle(0.0, 0.5, 0.0, 0.0, 0.3)], far_box, 0.1, 0.01,
                            1.0, 0.22)

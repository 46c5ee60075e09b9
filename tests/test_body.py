"""The formation's rigid motion (agent.body): the 3-variable QP against an oracle, the
footprint rows as CBF conditions on the twist, one sampled step that never crosses a wall, and the
member's nominal."""

from __future__ import annotations

import dataclasses
import math
import random
import warnings

import numpy as np
import pytest
import qpsolvers
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import sparse

from agent import body
from agent.barriers import Obstacle, ellipse_class_k
from geometry.ellipse import Ellipse, ellipse_value
from geometry.shapes import box, segment, shape_distance

PARAMS = body.BodyParams(vmax=0.22, omega_max=math.inf, gamma_obstacle=1.0, gamma_formations=1.0,
                         kp=2.0, dt=0.05)


def _oracle(zhat, rows):
    g = np.array([r[:3] for r in rows])
    h = np.array([r[3] for r in rows])
    with warnings.catch_warnings():  # an infeasible instance warns; None answers it
        warnings.simplefilter("ignore", UserWarning)
        x = qpsolvers.solve_qp(sparse.csc_matrix(2.0 * np.eye(3)), -2.0 * np.array(zhat),
                               sparse.csc_matrix(g), h, solver="clarabel", tol_gap_abs=1e-10,
                               tol_gap_rel=1e-10, tol_feas=1e-10, verbose=False)
    if x is None or np.max(g @ x - h) > 1e-6:
        return None
    return tuple(float(v) for v in x)


def _unit_row(rng: random.Random, centre):
    a = np.array([rng.gauss(0, 1) for _ in range(3)])
    a /= np.linalg.norm(a)
    margin = rng.choice([rng.uniform(0.0, 0.3), rng.uniform(-0.05, 0.3)])
    return (float(a[0]), float(a[1]), float(a[2]), float(a @ centre + margin))


def test_solve3_agrees_with_a_qpsolvers_oracle_on_random_instances():
    rng = random.Random(11)
    compared = infeasible = 0
    for _ in range(600):
        centre = np.array([rng.uniform(-0.3, 0.3) for _ in range(3)])
        rows = [_unit_row(rng, centre) for _ in range(rng.randint(1, 14))]
        zhat = tuple(rng.uniform(-0.5, 0.5) for _ in range(3))
        mine = body.solve3(zhat, rows)
        ref = _oracle(zhat, rows)
        if ref is None:
            assert mine is None or max(np.dot(r[:3], mine) - r[3] for r in rows) <= 1e-9
            infeasible += mine is None
            continue
        assert mine is not None, (zhat, rows)
        assert math.dist(mine, ref) <= 1e-5
        assert max(np.dot(r[:3], mine) - r[3] for r in rows) <= 1e-8
        compared += 1
    assert compared > 300 and infeasible >= 5


def test_the_twist_meets_every_row_and_is_relaxed_only_when_it_must():
    rng = random.Random(3)
    limits = body.twist_limit_rows(0.4, PARAMS)
    for _ in range(200):
        centre = np.array([rng.uniform(-0.05, 0.05) for _ in range(3)])
        rows = [_unit_row(rng, centre) for _ in range(rng.randint(1, 10))]
        goal = (rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-1.0, 1.0))
        res = body.solve_twist(goal, 0.4, limits, rows)
        z = (res.twist[0], res.twist[1], 0.4 * res.twist[2])
        assert max(np.dot(r[:3], z) - r[3] for r in limits) <= 1e-8  # limits: never relaxed
        assert max(np.dot(r[:3], z) - r[3] - res.slack for r in rows) <= 1e-8
        if body.solve3((0.0, 0.0, 0.0), [*limits, *rows]) is not None:
            assert res.slack == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi),
       st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-2.0, 2.0),
       st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_a_point_row_is_the_cbf_condition_on_the_points_velocity(cx, cy, th, vx, vy, w, px, py):
    """g . P' of the row's left side equals the directional derivative along the twist."""
    pose = body.Pose(cx, cy, th)
    sh = segment("w", (-2.0, -1.5), (2.0, -1.5), 0.15)
    p = (px, py)
    row = body.shape_point_row(pose, 0.5, p, sh, 0.15, 1.0)
    d0 = shape_distance(px, py, sh)[0]
    eps = 1e-6
    q = body.point_velocity(pose, (vx, vy, w), p)
    d1 = shape_distance(px + eps * q[0], py + eps * q[1], sh)[0]
    lhs = row[0] * vx + row[1] * vy + row[2] * 0.5 * w  # normalised: scale back by b
    assume(abs(row[3]) > 1e-6)
    scale = (1.0 * (d0 - 0.15)) / row[3]
    assert math.isclose(lhs * scale, -(d1 - d0) / eps, rel_tol=1e-3, abs_tol=1e-4)


def _moved(pose, twist, p, dt):
    """p (world) after dt of the rigid motion: the centroid on a line, the body turned about it."""
    c, s = math.cos(twist[2] * dt), math.sin(twist[2] * dt)
    rx, ry = p[0] - pose.cx, p[1] - pose.cy
    return (pose.cx + twist[0] * dt + c * rx - s * ry, pose.cy + twist[1] * dt + s * rx + c * ry)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)), min_size=2, max_size=5),
       st.floats(-math.pi, math.pi), st.floats(0.02, 0.1), st.floats(0.1, 1.0),
       st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-3.0, 3.0)),
       st.sampled_from(["wall", "box"]), st.floats(0.0, 0.4), st.booleans())
def test_a_footprint_point_never_crosses_a_wall_in_one_step(slots, th, dt, gdt, goal, kind, gap,
                                                            unicycle):
    """The discrete-time condition: with gamma dt <= 1 and the arc margin, every slot that starts
    at least Ds from a wall or shelf is still at least Ds from it after one period of the rigid
    motion the QP returns, for dt in [0.02, 0.1] (both robot models' turn limits)."""
    cx = sum(x for x, _ in slots) / len(slots)
    cy = sum(y for _, y in slots) / len(slots)
    offs = tuple((x - cx, y - cy) for x, y in slots)
    fp = body.Footprint(offs, 0.0, 0)
    assume(fp.rho > 0.05)
    p = PARAMS._replace(dt=dt, gamma_obstacle=gdt / dt, omega_max=2.84 if unicycle else math.inf)
    sh = (segment("w", (-3.0, -0.6), (3.0, -0.6), 0.15) if kind == "wall"
          else box("b", (0.0, -1.2), (2.0, 1.0), 0.3, 0.15))
    pose = body.Pose(0.0, 0.0, th)
    pts = [body.place(pose, o) for o in offs]
    lowest = min(shape_distance(x, y, sh)[0] for x, y in pts)
    margin = body.arc_margin(fp.rho, min(p.omega_max, p.vmax / fp.rho), dt)
    assume(lowest >= sh.ds + margin)  # the slots start inside the (grown) safe set
    rows = body.footprint_rows(fp, pose, body.Snapshot((), (sh,), ()), p)
    res = body.solve_twist(goal, fp.rho, body.twist_limit_rows(fp.rho, p), rows)
    assert res.slack == 0.0
    for q in pts:
        nx, ny = _moved(pose, res.twist, q, dt)
        assert shape_distance(nx, ny, sh)[0] >= sh.ds - 1e-9
    assert gap >= 0.0


def test_a_formation_backs_off_a_circle_coming_at_it_and_keeps_a_parked_one_out():
    fp = body.Footprint(((-0.25, 0.125), (0.25, 0.125), (0.25, -0.125), (-0.25, -0.125)), 0.0, 0)
    own = Ellipse(0.0, 0.0, 0.0, 0.5, 0.3)
    coming = Obstacle(1.0, 0.0, -0.3, 0.0, 0.5)
    _pose, res = body.formation_twist(fp, own, (5.0, 0.0), body.Snapshot((coming,), (), ()), PARAMS)
    assert res.twist[0] < 0.0  # it gives way along the approach, as one body
    parked = Obstacle(0.9, 0.0, 0.0, 0.0, 0.5)
    _pose, res = body.formation_twist(fp, own, (5.0, 0.0), body.Snapshot((parked,), (), ()), PARAMS)
    assert res.twist[0] < 0.22 * 0.9  # slowed short of it


def test_the_load_edge_keeps_a_shelf_corner_out_that_no_member_is_near():
    """A pair carrying a long load passes a box corner between its members: the members keep
    their distance, only the edge row stops the load cutting into the corner."""
    fp = body.footprint_of([(-0.6, 0.0), (0.6, 0.0)], [(-0.6, 0.0), (0.6, 0.0)],
                           [(-0.6, 0.0), (0.6, 0.0)], 0)
    corner_box = box("b", (0.0, -0.6), (0.4, 1.0), 0.0, 0.15)  # top face at y = -0.1
    pose = body.Pose(0.0, 0.0, 0.0)
    rows = body.footprint_rows(fp, pose, body.Snapshot((), (corner_box,), ()), PARAMS)
    res = body.solve_twist((0.0, -0.22, 0.0), fp.rho, body.twist_limit_rows(fp.rho, PARAMS), rows)
    assert res.twist[1] > -0.22 * 0.5
    no_load = dataclasses.replace(fp, load_edges=())
    rows = body.footprint_rows(no_load, pose, body.Snapshot((), (corner_box,), ()), PARAMS)
    free = body.solve_twist((0.0, -0.22, 0.0), fp.rho, body.twist_limit_rows(fp.rho, PARAMS), rows)
    assert free.twist[1] < res.twist[1] - 0.05


def test_a_member_at_its_slot_moves_with_the_twist_and_far_ones_are_pulled_back():
    fp = body.Footprint(((-0.25, 0.0), (0.25, 0.0)), 0.0, 1)
    pose = body.Pose(1.0, 1.0, 0.0)
    twist = (0.1, 0.0, 0.2)
    slot = body.place(pose, fp.slots[1])
    u = body.member_nominal(fp, pose, twist, slot, slot, (9.0, 9.0), PARAMS)
    assert math.isclose(u[0], 0.1) and math.isclose(u[1], 0.2 * 0.25)
    off = (slot[0] - 0.02, slot[1])
    v = body.member_nominal(fp, pose, twist, off, off, (9.0, 9.0), PARAMS)
    assert v[0] > u[0]


def test_a_member_settles_on_its_target_only_where_it_arrives_not_at_a_waypoint_passed():
    """At its target (its goal, or its slot where the formation holds) a member blends into
    eq. 4.2 on it and keeps only what the rows changed of the goal twist; at a waypoint the
    formation passes it keeps its slot's motion, the turn to the waypoint's heading included
    (blended there, a pentagon in the warehouse never turned and never passed it)."""
    fp = body.Footprint(((-0.25, 0.0), (0.25, 0.0)), 0.0, 1)
    pose = body.Pose(1.0, 1.0, 0.0)
    turn = (0.0, 0.0, 0.4)  # the goal twist: turn in place
    slot = body.place(pose, fp.slots[1])
    settle = body.member_nominal(fp, pose, turn, slot, slot, slot, PARAMS, turn)
    assert math.hypot(*settle) < 1e-12  # at its target: nothing left to do
    passing = body.member_nominal(fp, pose, turn, slot, slot, slot, PARAMS, turn, arriving=False)
    assert math.isclose(passing[0], 0.0, abs_tol=1e-12) and math.isclose(passing[1], 0.4 * 0.25)


def test_a_member_arriving_under_a_slowed_twist_keeps_its_pull_and_gives_way_to_a_push():
    """Rows that slow the goal twist to a crawl (another formation's ellipse beside the goal)
    take off only the share of the goal they carry: the member still closes on its target
    (rigid-doorway-four-unicycle stopped 57 mm short when the whole goal came off); rows that
    push the formation away keep the whole push."""
    fp = body.Footprint(((-0.25, 0.0), (0.25, 0.0)), 0.0, 1)
    pose = body.Pose(1.0, 1.0, 0.0)
    goal = (0.05, 0.0, 0.0)  # the goal twist: on towards +x
    slot = body.place(pose, fp.slots[1])
    target = (slot[0] + 0.05, slot[1])  # half ARRIVE_RANGE ahead
    w = 0.5  # halfway into the blend
    crawl = body.member_nominal(fp, pose, (0.01, 0.0, 0.0), slot, slot, target, PARAMS, goal)
    # (1 - w) of the crawl and w of eq. 4.2's whole pull; taking off w of the whole goal left
    # 0.01 - w 0.05 + w kp 0.05 = 0.035, the crawl's shortfall pulling back against the pull
    assert math.isclose(crawl[0], (1 - w) * 0.01 + w * PARAMS.kp * 0.05)
    assert math.isclose(crawl[1], 0.0, abs_tol=1e-12)
    push = body.member_nominal(fp, pose, (-0.03, 0.02, 0.0), slot, slot, target, PARAMS, goal)
    assert math.isclose(push[1], 0.02)  # sideways: what the rows added, kept whole
    assert math.isclose(push[0], -0.03 + w * (PARAMS.kp * 0.05))  # the push back, kept whole


def test_the_goal_turn_of_a_rotated_goal_shape():
    starts = [(0.0, 0.0), (1.0, 0.0), (1.0, 0.5)]
    goals = [(5.0, 5.0), (5.0, 6.0), (4.5, 6.0)]  # turned by +90 degrees
    fp = body.footprint_of(starts, starts, goals, 0)
    assert math.isclose(fp.goal_turn, math.pi / 2, abs_tol=1e-9)


@settings(max_examples=300, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(0.01, 0.22), st.floats(0.05, 1.0),
       st.floats(0.05, 3.0), st.floats(-1.4, 1.4), st.floats(0.0, 0.22), st.floats(-1.0, 1.0),
       st.floats(0.0, 2.0 * math.pi))
def test_spread_rows_keep_the_slots_velocities_within_the_spread(heading, speed, rho, spread,
                                                                   off, norm, frac, at):
    """A twist meeting the spread rows of a goal without turn moves every point of the body
    (within rho of the centroid) within spread / 2 of the twist's own direction of travel, so
    members aligned with their slots' velocities differ in heading by at most the spread; and
    the rows allow every turn up to that bound (drawn: a travel within 80 degrees of the goal's,
    a turn rate a fraction of the bound)."""
    goal = (speed * math.cos(heading), speed * math.sin(heading), 0.0)
    rows = body.spread_rows(goal, rho, spread)
    v = (norm * math.cos(heading + off), norm * math.sin(heading + off))
    assume(norm * math.cos(off) > 1e-6)
    bound = math.sin(0.5 * spread) * norm * math.cos(off) / rho  # [rad/s]
    w = frac * bound
    z = (v[0], v[1], rho * w)
    assert all(a1 * z[0] + a2 * z[1] + a3 * z[2] <= b + 1e-12 for a1, a2, a3, b in rows)
    outside = (v[0], v[1], math.copysign(rho * bound * 1.01 + 1e-9, frac))
    assert any(a1 * outside[0] + a2 * outside[1] + a3 * outside[2] > b for a1, a2, a3, b in rows)
    r = (rho * math.cos(at), rho * math.sin(at))
    sv = (v[0] - w * r[1], v[1] + w * r[0])
    cos = (sv[0] * v[0] + sv[1] * v[1]) / (math.hypot(*sv) * math.hypot(*v))
    assert math.acos(max(-1.0, min(1.0, cos))) <= 0.5 * spread + 1e-9


def test_spread_rows_leave_the_goals_turn_and_give_way_to_the_barriers():
    """The goal's own turn is a twist the rows allow (a formation turning to its goal shape), a
    turn with no travel is only the goal's, single integrators get none, and where a barrier row
    needs a turn the spread rows forbid, the barrier wins (the rows are left out)."""
    rho = 0.4
    limits = body.twist_limit_rows(rho, PARAMS)
    goal = (0.1, 0.0, 0.2)  # within the slots' speed limit: 0.1 + rho 0.2 < 0.22 cos 15 deg
    assert body.solve_twist(goal, rho, limits, [], body.spread_rows(goal, rho, 0.8)).twist == \
        pytest.approx(goal)
    still = body.spread_rows((0.0, 0.0, 0.0), rho, 0.8)
    assert body.solve_twist((0.0, 0.0, 0.5), rho, limits, [], still).twist == \
        pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert body.spread_rows(goal, rho, math.inf) == []
    # a barrier row that needs the body to turn by at least 0.4 rad/s: rho omega >= 0.16
    turn = [(0.0, 0.0, -1.0, -0.16)]
    res = body.solve_twist((0.2, 0.0, 0.0), rho, limits, turn, body.spread_rows((0.2, 0.0, 0.0),
                                                                                  rho, 0.1))
    assert res.twist[2] * rho >= 0.16 - 1e-9 and res.slack == 0.0


# --- two formations: each keeps its own ellipse off the other's members (the mirror rows) ------


def _turned(e: Ellipse, twist, dt: float) -> Ellipse:
    """``e`` moved rigidly by ``twist`` about its centre for dt."""
    return e._replace(cx=e.cx + twist[0] * dt, cy=e.cy + twist[1] * dt,
                      alpha=e.alpha + twist[2] * dt)


def _h(e: Ellipse, q, grow: float = 0.0) -> float:
    return ellipse_value(e._replace(a=e.a + grow, b=e.b + grow), q[0], q[1])


@settings(max_examples=300, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi),
       st.floats(0.3, 1.2), st.floats(0.2, 1.0), st.floats(0.0, 0.1),
       st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-2.0, 2.0)),
       st.tuples(st.floats(-2.5, 2.5), st.floats(-2.5, 2.5)), st.floats(0.1, 0.8))
def test_a_mirror_row_is_half_the_cbf_condition_on_the_own_ellipse_over_a_member_point(
        cx, cy, alpha, a, aspect, grow, twist, q, rho):
    """The row's left side is -dh/dt of h = h_own(q) (eq. 4.6, the own ellipse grown by the load
    margin) under the twist, q held still; its right side is half of alpha(h)."""
    own = Ellipse(cx, cy, alpha, a, a * aspect)
    assume(abs(_h(own, q, grow)) > 1e-3 and math.dist(q, (cx, cy)) > 0.05)  # a gradient
    p = PARAMS._replace(load_margin=grow)
    other = Ellipse(q[0] + 0.5, q[1], 0.0, 0.6, 0.3, points=(q,))
    (row,) = body.mirror_rows(own, body.Pose(cx, cy, alpha), rho, [other], p)
    z = (twist[0], twist[1], rho * twist[2])
    lhs = row[0] * z[0] + row[1] * z[1] + row[2] * z[2]
    eps = 1e-6  # central difference: h is far from linear in the turn for a thin ellipse
    dh = (_h(_turned(own, twist, eps), q, grow) - _h(_turned(own, twist, -eps), q, grow)) / (2 * eps)
    h = _h(own, q, grow)
    half_alpha = body.BODY_TUNING.mirror_share * ellipse_class_k(h, p.gamma_formations)
    scale = half_alpha / row[3]  # the row is normalised: both sides by one positive factor
    assert scale > 0.0
    assert math.isclose(lhs * scale, -dh, rel_tol=1e-3, abs_tol=1e-5)


@settings(max_examples=300, deadline=None)
@given(st.floats(0.4, 1.2), st.floats(0.3, 1.0), st.floats(-math.pi, math.pi),
       st.floats(0.0, 2.0 * math.pi), st.floats(0.02, 0.8),
       st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-2.0, 2.0)),
       st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-2.0, 2.0)))
def test_the_two_halves_add_up_to_appendix_a3_on_the_pair(a, aspect, alpha, bearing, gap,
                                                          goal_a, goal_b):
    """Formation B's slot q outside A's ellipse: B's twist keeps q off A's ellipse by half of
    alpha (crediting nothing of A's motion), A's twist keeps its ellipse off q by the other
    half; whatever each asks for, dh/dt >= -alpha(h) for h = h_A(q) under both motions."""
    p = PARAMS._replace(load_margin=0.05)
    grow = p.load_margin
    own_a = Ellipse(0.0, 0.0, alpha, a, a * aspect)
    # q on the ray at ``bearing``, ``gap`` beyond A's grown ellipse
    dx, dy = math.cos(bearing), math.sin(bearing)
    lo, hi = 0.0, 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _h(own_a, (mid * dx, mid * dy), grow) < 0.0 else (lo, mid)
    q = ((hi + gap) * dx, (hi + gap) * dy)
    pose_b = body.Pose(q[0] + 0.15, q[1], 0.0)  # B's slots: q and one 0.3 m beside it
    own_b = Ellipse(q[0] + 0.15, q[1], 0.0, 0.5, 0.3, points=(q, (q[0] + 0.3, q[1])))
    a_sends = own_a._replace(points=((0.0, 0.0),))
    row_b = body.ellipse_point_row(pose_b, 0.3, q, a_sends, p.gamma_formations, grow)
    (row_a, _) = body.mirror_rows(own_a, body.Pose(0.0, 0.0, alpha), 0.5, [own_b], p)
    tw_a = body.solve_twist(goal_a, 0.5, body.twist_limit_rows(0.5, p), [row_a]).twist
    tw_b = body.solve_twist(goal_b, 0.3, body.twist_limit_rows(0.3, p), [row_b]).twist
    eps = 1e-6
    q1 = body.point_velocity(pose_b, tw_b, q)
    h0 = _h(own_a, q, grow)
    h1 = _h(_turned(own_a, tw_a, eps), (q[0] + eps * q1[0], q[1] + eps * q1[1]), grow)
    assert (h1 - h0) / eps >= -ellipse_class_k(h0, p.gamma_formations) - 1e-4


def test_a_formation_does_not_chase_a_smaller_one_its_ellipse_reaches():
    """A long pair drives at a small formation whose members its ellipse (round its own
    members' clearance disks) is about to cover, while its own members are far from the small
    one's ellipse: without the other's points it drives on at full speed (its ellipse then
    sweeps over the small one, which must flee); with them it slows to keep its
    ellipse off them."""
    fp = body.Footprint(((-0.6, 0.0), (0.6, 0.0)), 0.0, 0)
    own = Ellipse(0.0, 0.0, 0.0, 1.0, 0.3)
    small = Ellipse(1.3, 0.0, 0.0, 0.25, 0.2, points=((1.15, 0.0), (1.45, 0.0)))
    legacy = small._replace(points=())
    goal = (5.0, 0.0)
    _pose, free = body.formation_twist(fp, own, goal, body.Snapshot((), (), (legacy,)), PARAMS)
    _pose, held = body.formation_twist(fp, own, goal, body.Snapshot((), (), (small,)), PARAMS)
    assert free.twist[0] > 0.2
    assert 0.0 < held.twist[0] < 0.1
    # and nothing of its own members' rows changed: they are far from the small ellipse
    h_slot = ellipse_value(small, 0.6, 0.0)
    assert h_slot > 5.0


# --- a body that turns back brakes first ------------------------------------------------------


def test_a_formation_asked_to_turn_back_brakes_first_and_then_goes():
    """A pair driving east at 0.2 m/s whose new route leads west keeps driving east, slowed by
    BRAKE_DECEL dt a tick, until it is slower than BRAKE_FROM; then the route's twist holds.
    No slot's command flips by more than 90 degrees between two ticks while it is fast."""
    offsets = [(-0.3, 0.0), (0.3, 0.0)]
    dt = 0.05
    want = (-0.2, 0.0, 0.0)
    moving = (0.2, 0.0, 0.0)
    ticks = 0
    while True:
        got = body.brake_before_turning_back(want, moving, offsets, dt)
        if got == want:
            break
        assert got[0] > 0.0 and got[1] == 0.0
        assert math.isclose(got[0], moving[0] - body.BODY_TUNING.brake_decel * dt)
        moving = got  # the members follow the braked twist
        ticks += 1
    assert moving[0] <= body.BODY_TUNING.brake_from + 1e-12
    t = body.BODY_TUNING
    assert ticks == math.ceil((0.2 - t.brake_from) / (t.brake_decel * dt) - 1e-9)


def test_a_turn_that_sends_an_outer_slot_back_brakes_too_and_a_sideways_one_does_not():
    offsets = [(-0.6, 0.0), (0.6, 0.0)]
    moving = (0.0, 0.15, 0.0)  # north
    # the centroid keeps going north, but a fast turn sends the east slot south
    spin = (0.0, 0.05, 0.4)
    assert body.brake_before_turning_back(spin, moving, offsets, 0.05) != spin
    # east is 90 degrees off: no slot turns back
    east = (0.15, 0.0, 0.0)
    assert body.brake_before_turning_back(east, moving, offsets, 0.05) == east
    # nearly at rest: nothing to brake
    slow = (0.0, 0.03, 0.0)
    assert body.brake_before_turning_back((0.0, -0.2, 0.0), slow, offsets, 0.05) == (0.0, -0.2, 0.0)


# --- a formation of unicycles waits for its members to face its motion ------------------------


UNI = PARAMS._replace(spread=0.05 / 0.05)  # unicycle members: epsilon / offset
PAIR = body.Footprint(((-0.3, 0.0), (0.3, 0.0)), 0.0, 0)


@settings(max_examples=300, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(body.BODY_TUNING.pace_moving, 0.22), st.floats(-0.5, 0.5),
       st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3), st.integers(0, 2),
       st.floats(0.0, math.pi))
def test_the_pace_is_set_by_the_member_facing_its_slots_motion_worst(
        travel, speed, omega, offs, which, worse):
    """Full pace with every member within PACE_ALIGNED of its slot's motion, the floor with one
    PACE_SIDEWAYS off or more, in between otherwise; turning a member further from its slot's
    motion never raises it."""
    fp = body.Footprint(((-0.3, 0.0), (0.3, 0.0), (0.0, 0.4)), 0.0, 0)
    pose = body.Pose(1.0, -2.0, 0.3)
    want = (speed * math.cos(travel), speed * math.sin(travel), omega)
    vel = [body.point_velocity(pose, want, body.place(pose, q)) for q in fp.slots]
    assume(all(math.hypot(*v) >= body.BODY_TUNING.pace_from for v in vel))
    assume(max(math.hypot(*v) for v in vel) >= body.BODY_TUNING.pace_moving + 1e-9)  # a formation that moves
    dirs = [math.atan2(v[1], v[0]) for v in vel]
    k = body.pace(want, pose, fp, [d + o for d, o in zip(dirs, offs, strict=True)])
    worst = max(abs(body.wrap_angle(o)) for o in offs)
    assert body.BODY_TUNING.pace_floor <= k <= 1.0
    if worst <= body.BODY_TUNING.pace_aligned - 1e-9:
        assert k == 1.0
    if worst >= body.BODY_TUNING.pace_sideways + 1e-9:
        assert k == body.BODY_TUNING.pace_floor
    if body.BODY_TUNING.pace_aligned + 1e-6 < worst < body.BODY_TUNING.pace_sideways - 1e-6:
        assert k < 1.0
    # one member turned further away (by up to half a turn, not past behind): never faster
    o = abs(body.wrap_angle(offs[which]))
    turned = list(offs)
    turned[which] = math.copysign(min(math.pi, o + worse), body.wrap_angle(offs[which]) or 1.0)
    assert body.pace(want, pose, fp, [d + t for d, t in zip(dirs, turned, strict=True)]) <= k + 1e-12


def test_a_slow_formation_does_not_wait_and_a_slow_slot_is_not_waited_for():
    pose = body.Pose(0.0, 0.0, 0.0)
    slow = (body.BODY_TUNING.pace_moving * 0.9, 0.0, 0.0)
    assert body.pace(slow, pose, PAIR, [math.pi, math.pi]) == 1.0  # both face back, but it creeps
    # a pair spinning about its first member's slot: that slot stands, the other moves fast
    spin = (0.0, -0.6 * 0.3, 0.6)
    fp = body.Footprint(((0.0, 0.0), (0.6, 0.0)), 0.0, 0)
    vel = body.point_velocity(pose, spin, body.place(pose, fp.slots[1]))
    assert math.hypot(*vel) > body.BODY_TUNING.pace_moving
    facing = math.atan2(vel[1], vel[0])
    assert body.pace(spin, pose, fp, [facing + math.pi, facing]) == 1.0
    assert body.pace(spin, pose, fp, [facing, facing + math.pi]) == body.BODY_TUNING.pace_floor


def test_a_formation_whose_members_face_back_asks_for_the_floor_and_aims_at_the_full_twist():
    """A pair at rest whose goal lies behind its members: the twist is the floor's share of the
    one certified for the full goal, which is the aim its members turn to face; once they face
    it, the formation drives at the full twist and there is nothing to aim at. Single
    integrators (no spread limit) never wait."""
    own = Ellipse(0.0, 0.0, 0.0, 0.6, 0.2, headings=(math.pi, math.pi))
    goal = (-5.0, 0.0)
    snap = body.Snapshot((), (), ())
    _pose, full = body.formation_twist(PAIR, own._replace(headings=()), goal, snap, UNI)
    _pose, waiting = body.formation_twist(PAIR, own._replace(headings=(0.0, 0.1)), goal, snap, UNI)
    assert full.twist[0] < -0.2 and full.aim is None
    assert waiting.aim == pytest.approx(full.twist)
    assert waiting.twist[0] == pytest.approx(body.BODY_TUNING.pace_floor * full.twist[0])
    _pose, facing = body.formation_twist(PAIR, own, goal, snap, UNI)
    assert facing.twist == pytest.approx(full.twist) and facing.aim is None
    _pose, holonomic = body.formation_twist(PAIR, own._replace(headings=(0.0, 0.1)), goal, snap,
                                            PARAMS)
    assert holonomic.aim is None and holonomic.twist[0] < -0.2


def test_a_twist_memo_shares_one_twist_among_members_and_follows_a_changed_input():
    """Every member's slot gets the twist formation_twist gives; a thing that moved (even in
    a list changed in place) is a new twist."""
    slots = ((-0.25, 0.125), (0.25, 0.125), (0.25, -0.125), (-0.25, -0.125))
    own = Ellipse(0.0, 0.0, 0.0, 0.5, 0.3)
    things = [Obstacle(1.0, 0.0, -0.3, 0.0, 0.5)]
    memo = body.TwistMemo()
    want = body.formation_twist(body.Footprint(slots, 0.0, 0), own, (5.0, 0.0),
                                body.Snapshot(things, (), ()), PARAMS)
    for member in range(4):
        got = memo.twist(body.Footprint(slots, 0.0, member), own, (5.0, 0.0),
                         body.Snapshot(things, (), ()), PARAMS)
        assert got == want
    things[0] = Obstacle(3.0, 0.0, 0.0, 0.0, 0.5)  # the same list, the circle gone farther
    moved = memo.twist(body.Footprint(slots, 0.0, 0), own, (5.0, 0.0),
                       body.Snapshot(things, (), ()), PARAMS)
    assert moved == body.formation_twist(body.Footprint(slots, 0.0, 0), own, (5.0, 0.0),
                                         body.Snapshot(things, (), ()), PARAMS)
    assert moved[1].twist[0] > want[1].twist[0]


def test_a_twist_memo_keeps_one_twist_per_formation_of_one_shape():
    """Two formations of one shape heading for different goals, served in turn by one memo
    (an agent host's): each keeps its own twist, handed out again without a new solve."""
    slots = ((-0.25, 0.125), (0.25, 0.125), (0.25, -0.125), (-0.25, -0.125))
    memo = body.TwistMemo()
    snap = body.Snapshot((Obstacle(1.0, 0.0, -0.3, 0.0, 0.5),), (), ())
    own_a, own_b = Ellipse(0.0, 0.0, 0.0, 0.5, 0.3), Ellipse(0.0, 3.0, 0.0, 0.5, 0.3)
    first_a = memo.twist(body.Footprint(slots, 0.0, 0), own_a, (5.0, 0.0), snap, PARAMS)
    first_b = memo.twist(body.Footprint(slots, 0.0, 0), own_b, (5.0, 3.0), snap, PARAMS)
    again_a = memo.twist(body.Footprint(slots, 0.0, 1), own_a, (5.0, 0.0), snap, PARAMS)
    again_b = memo.twist(body.Footprint(slots, 0.0, 2), own_b, (5.0, 3.0), snap, PARAMS)
    assert again_a is first_a and again_b is first_b
    assert first_a == body.formation_twist(body.Footprint(slots, 0.0, 3), own_a, (5.0, 0.0),
                                           snap, PARAMS)
    assert first_a != first_b

"""Control design: hard separation with a sound split, escape from moving hazards,
unicycle bodies through the headings, all-to-all with the same formation-level rules."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import barriers, unicycle
from agent.barriers import Neighbour, Obstacle, Partner
from agent.control import Controller, ControlParams, FormationView, StepInput, escape_command
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, solve_exact
from formation.cli import main
from leader.ellipse import Ellipse
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[1]
SI = ControlParams(tiebreak=False)
DSEP = SI.separation  # two radii
DT = SI.period

coord = st.floats(-1.0, 1.0)
speed = st.floats(0.0, 0.22)
angle = st.floats(-math.pi, math.pi)


def _velocity(s: float, a: float) -> tuple[float, float]:
    return (s * math.cos(a), s * math.sin(a))


def _both_step(p: ControlParams, pose_i, pose_j, v_i, v_j, goal_i, goal_j):
    """Both robots solve at the same time from the same snapshot, each with the other as a
    separation partner (its control point, last velocity and heading, as its state gives)."""
    ci = unicycle.control_point(*pose_i, p.offset)
    cj = unicycle.control_point(*pose_j, p.offset)
    ri = Controller(p).step(StepInput(pose_i, goal_i, partners=[Partner(*cj, *v_j, pose_j[2])], last_u=v_i))
    rj = Controller(p).step(StepInput(pose_j, goal_j, partners=[Partner(*ci, *v_i, pose_i[2])], last_u=v_j))
    return ri, rj


@settings(max_examples=150, deadline=None)
@given(coord, coord, st.floats(0.0, 0.3), angle, speed, angle, speed, angle, st.tuples(coord, coord),
       st.tuples(coord, coord))
def test_two_robots_solving_at_once_never_get_closer_than_two_radii(
    x, y, gap, bearing, si, ai, sj, aj, goal_i, goal_j,
):
    # Any start at least two radii apart, any last velocities (consistent or not), any goals
    # (the nominal command drives them anywhere, through each other too).
    pi = (x, y, 0.0)
    pj = (x + (DSEP + gap) * math.cos(bearing), y + (DSEP + gap) * math.sin(bearing), 0.0)
    vi, vj = _velocity(si, ai), _velocity(sj, aj)
    ri, rj = _both_step(SI, pi, pj, vi, vj, (goal_i[0] * 3, goal_i[1] * 3), (goal_j[0] * 3, goal_j[1] * 3))
    if STATUS_FALLBACK in (ri.status, rj.status) or STATUS_FAILED in (ri.status, rj.status):
        return  # a hard row could not be met: counted, and not what this property is about
    xi, yi = pi[0] + ri.ux * DT, pi[1] + ri.uy * DT
    xj, yj = pj[0] + rj.ux * DT, pj[1] + rj.uy * DT
    h0 = (DSEP + gap) ** 2 - DSEP**2
    h1 = (xi - xj) ** 2 + (yi - yj) ** 2 - DSEP**2
    assert h1 >= (1.0 - SI.gamma_formation * DT) * h0 - 1e-12
    assert math.hypot(xi - xj, yi - yj) >= DSEP - 1e-12


@settings(max_examples=80, deadline=None)
@given(coord, coord, st.floats(0.0, 0.3), angle, speed, angle, speed, angle)
def test_a_pair_safe_at_its_last_velocities_always_finds_its_rows_feasible(
    x, y, gap, bearing, si, ai, sj, aj,
):
    pi = (x, y, 0.0)
    pj = (x + (DSEP + gap) * math.cos(bearing), y + (DSEP + gap) * math.sin(bearing), 0.0)
    vi, vj = _velocity(si, ai), _velocity(sj, aj)
    h, gi, gj = barriers.separation_terms(pi[:2], 0.0, pj[:2], 0.0, DSEP, 0.0)
    c = SI.gamma_formation * h + gi[0] * vi[0] + gi[1] * vi[1] + gj[0] * vj[0] + gj[1] * vj[1]
    ri, rj = _both_step(SI, pi, pj, vi, vj, (pj[0], pj[1]), (pi[0], pi[1]))  # head for each other
    if c >= 0.0:
        assert ri.status == "ok" and rj.status == "ok"


def test_counting_on_the_neighbours_last_velocity_lets_two_robots_acting_at_once_cross():
    # Appendix A.2's form: each robot treats the other as moving on with its last velocity.
    # Both last moved apart at full speed, both now turn towards each other: each row allows it.
    pi, pj = (0.0, 0.0), (DSEP + 0.005, 0.0)
    vi, vj = (-0.22, 0.0), (0.22, 0.0)
    rows_i = [barriers.pairwise_row(*pi, Neighbour(*pj, *vj, 0.0), DSEP, 1.0)[1]]
    rows_j = [barriers.pairwise_row(*pj, Neighbour(*pi, *vi, 0.0), DSEP, 1.0)[1]]
    ui = solve_exact(0.22, 0.0, rows_i + barriers.speed_rows(0.22, 0.0))
    uj = solve_exact(-0.22, 0.0, rows_j + barriers.speed_rows(0.22, math.pi))
    assert ui is not None and uj is not None  # both QPs are "ok"
    gap = (pj[0] + uj[0] * DT) - (pi[0] + ui[0] * DT)
    assert gap < DSEP  # ... and they overlap
    # The reciprocal split on the same data holds them apart.
    ri, rj = _both_step(SI, (*pi, 0.0), (*pj, 0.0), vi, vj, (5.0, 0.0), (-5.0, 0.0))
    assert (pj[0] + rj.ux * DT) - (pi[0] + ri.ux * DT) >= DSEP - 1e-12


@settings(max_examples=8, deadline=None)
@given(angle, st.floats(-0.3, 0.3), angle, angle)
def test_two_unicycles_swapping_places_keep_their_bodies_apart_for_the_whole_run(a, off, ti, tj):
    p = ControlParams(unicycle=True, tiebreak=False)
    c, s = math.cos(a), math.sin(a)
    pose_i = [-1.0 * c - off * s, -1.0 * s + off * c, ti]
    pose_j = [1.0 * c, 1.0 * s, tj]
    goal_i, goal_j = (pose_j[0], pose_j[1]), (pose_i[0], pose_i[1])
    vi = vj = (0.0, 0.0)
    for _ in range(400):
        ri, rj = _both_step(p, tuple(pose_i), tuple(pose_j), vi, vj, goal_i, goal_j)
        pose_i = list(unicycle.integrate(*pose_i, ri.v, ri.omega, DT))
        pose_j = list(unicycle.integrate(*pose_j, rj.v, rj.omega, DT))
        vi, vj = (ri.ux, ri.uy), (rj.ux, rj.uy)
        assert math.dist(pose_i[:2], pose_j[:2]) >= 2 * p.radius - 1e-9


def test_separation_terms_match_finite_differences_of_the_unicycle_barrier():
    la, dsep = 0.05, 0.21
    pi, pj, ti, tj = (0.1, 0.2), (0.45, 0.1), 0.7, -1.9
    ui, uj = (0.13, -0.05), (-0.02, 0.17)

    def h_at(t: float) -> float:
        def move(p, th, u):  # the look-ahead point moves with u, the heading with eq. 6.2
            v, w = unicycle.to_unicycle(*u, th, la)
            return (p[0] + u[0] * t, p[1] + u[1] * t), th + w * t
        a, ta = move(pi, ti, ui)
        b, tb = move(pj, tj, uj)
        return barriers.separation_terms(a, ta, b, tb, dsep, la)[0]

    h, gi, gj = barriers.separation_terms(pi, ti, pj, tj, dsep, la)
    rate = gi[0] * ui[0] + gi[1] * ui[1] + gj[0] * uj[0] + gj[1] * uj[1]
    eps = 1e-6
    assert rate == pytest.approx((h_at(eps) - h_at(-eps)) / (2 * eps), abs=1e-6)
    # and h >= 0 means the bodies (behind the points) are dsep apart
    bi = (pi[0] - la * math.cos(ti), pi[1] - la * math.sin(ti))
    bj = (pj[0] - la * math.cos(tj), pj[1] - la * math.sin(tj))
    assert h >= 0 and math.dist(bi, bj) >= dsep


# ------------------------------------------------------------------------------- escape


def _view(cx, cy, gx, gy) -> FormationView:
    return FormationView(Ellipse(cx, cy, 0.0, 0.6, 0.45), gx, gy, "A")


def test_a_parked_formation_on_a_fast_hazards_path_steps_aside_and_a_static_or_passing_one_does_not():
    p = ControlParams()
    parked = _view(0.0, 0.0, 0.0, 0.0)
    forklift = Obstacle(-4.0, 0.0, 0.33, 0.0, 0.5)  # 1.5 x top speed, from behind
    ux, uy = escape_command(p, parked, [forklift])
    assert abs(ux) < 1e-9 and uy < -0.1  # sideways, to the forklift's right, at speed
    assert escape_command(p, parked, [Obstacle(-4.0, 0.0, 0.0, 0.0, 0.5)]) is None
    assert escape_command(p, parked, [Obstacle(-4.0, 2.5, 0.33, 0.0, 0.5)]) is None  # wide of us
    assert escape_command(p, parked, [Obstacle(1.0, 0.0, 0.33, 0.0, 0.5)]) is None  # gone past
    # off its centre line: away from the line, whichever side we are on
    assert escape_command(p, _view(0.0, 0.3, 0.0, 0.3), [forklift])[1] > 0.1


def test_a_formation_crossing_the_path_of_a_hazard_as_fast_as_itself_gives_way():
    p = ControlParams()
    crossing = _view(0.0, -1.2, 0.0, 6.0)  # wants to cross y = 0 going north
    forklift = Obstacle(-1.5, 0.0, 0.21, 0.0, 0.5)  # crossing at 0.95 x top speed, close
    ux, uy = escape_command(p, crossing, [forklift])
    assert uy <= 1e-9  # no motion towards the hazard's path line: it waits or backs off
    # a slow hazard far off leaves it alone: it crosses well ahead
    assert escape_command(p, crossing, [Obstacle(-5.9, 0.0, 0.03, 0.0, 0.5)]) is None


def test_escape_is_the_same_vector_for_every_member():
    from agent.body import footprint_of

    p = ControlParams(tiebreak=True)
    view = _view(0.0, 0.0, 0.0, 0.0)
    forklift = [Obstacle(-4.0, 0.0, 0.33, 0.0, 0.5)]
    members = [(0.25, 0.125), (0.25, -0.125), (-0.25, -0.125), (-0.25, 0.125)]
    noms = set()
    for k, (x, y) in enumerate(members):  # each member at its slot of the formation's body
        fp = footprint_of(members, members, members, k)
        r = Controller(p).step(StepInput((x, y, 0.0), (x, y), obstacles=forklift, view=view, footprint=fp))
        noms.add((round(r.nominal_ux, 12), round(r.nominal_uy, 12), r.escape))
    assert len(noms) == 1 and next(iter(noms))[2]


# ---------------------------------------------------------------- all-to-all and the check


def test_all_to_all_keeps_the_tie_break_and_resolves_the_head_on_meeting():
    scenario = load_scenario(ROOT / "tests/scenarios/head-on-rectangles.yaml")
    s = simulate(scenario, SimOptions(record=False, topology="all-to-all")).summary
    assert s["all_reached"] and s["collisions"] == 0
    assert s["comm"]["messages"] > 0


def test_check_warns_where_the_band_lets_bodies_touch_and_still_accepts_the_file(capsys):
    # (the warehouse's rectangles are 0.3 m wide now; this file keeps 0.25 m with epsilon 0.04)
    assert main(["check", str(ROOT / "tests/scenarios/head-on-rectangles.yaml")]) == 0
    err = capsys.readouterr().err
    assert "warning: formations[0].edges[1]: Df - epsilon = 0.210 m lets the bodies" in err
    assert "separation rows keep them apart" in err
    assert main(["check", str(ROOT / "scenarios/thesis-5.2.1.yaml")]) == 0
    assert "warning" not in capsys.readouterr().err

"""The exact 2-variable QP against qpsolvers backends, and the relaxation policy."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.qp import (
    FEAS_TOL,
    STATUS_FALLBACK,
    STATUS_OK,
    STATUS_RELAXED,
    make_solver,
    normalized_row,
    qpsolvers_solver,
    solve_cbf_qp,
    solve_exact,
)


def random_instance(rng: random.Random, m: int):
    """Rows around a random interior point (so most instances are feasible) plus some
    arbitrary rows (so some are not)."""
    cx, cy = rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
    rows = []
    for _ in range(m):
        phi = rng.uniform(0, 2 * math.pi)
        ax, ay = math.cos(phi), math.sin(phi)
        margin = rng.choice([rng.uniform(0.0, 0.3), rng.uniform(-0.05, 0.3)])
        rows.append((ax, ay, ax * cx + ay * cy + margin))
    ux, uy = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)
    return ux, uy, rows


def violation(u, rows) -> float:
    return max((ax * u[0] + ay * u[1] - b for ax, ay, b in rows), default=-1.0)


def test_exact_solver_agrees_with_osqp_on_thousands_of_random_instances():
    osqp = qpsolvers_solver("osqp")
    rng = random.Random(7)
    compared = infeasible = 0
    for _ in range(3000):
        ux, uy, rows = random_instance(rng, rng.randint(1, 16))
        mine = solve_exact(ux, uy, rows)
        ref = osqp(ux, uy, rows)
        if ref is None:
            assert mine is None or violation(mine, rows) <= 1e-9
            infeasible += mine is None
            continue
        assert mine is not None, (ux, uy, rows)
        assert math.dist(mine, ref) <= 1e-6
        compared += 1
    assert compared > 2000 and infeasible > 20


@pytest.mark.parametrize("backend", ["daqp", "quadprog", "clarabel"])
def test_exact_solver_agrees_with_other_backends(backend):
    ref_solve = qpsolvers_solver(backend)
    rng = random.Random(11)
    compared = 0
    for _ in range(800):
        ux, uy, rows = random_instance(rng, rng.randint(1, 12))
        mine = solve_exact(ux, uy, rows)
        ref = ref_solve(ux, uy, rows)
        if ref is None or mine is None:
            assert (ref is None) == (mine is None) or (
                mine is not None and violation(mine, rows) <= 1e-6
            )
            continue
        assert math.dist(mine, ref) <= 1e-6
        compared += 1
    assert compared > 500


def test_infeasible_instances_are_reported_as_none():
    rows = [(1.0, 0.0, -0.1), (-1.0, 0.0, -0.1)]  # x <= -0.1 and x >= 0.1
    assert solve_exact(0.0, 0.0, rows) is None
    assert solve_exact(0.0, 0.0, [(0.0, 0.0, -1.0)]) is None


def test_unconstrained_nominal_is_returned_unchanged():
    assert solve_exact(0.1, -0.2, [(1.0, 0.0, 1.0)]) == (0.1, -0.2)


def test_hand_checked_vertex_solution():
    # x <= 0, y <= 0 from (1, 1): the corner (0, 0).
    u = solve_exact(1.0, 1.0, [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
    assert u == pytest.approx((0.0, 0.0), abs=1e-12)
    # x + y <= 1 from (1, 1): projection (0.5, 0.5).
    u = solve_exact(1.0, 1.0, [normalized_row(1.0, 1.0, 1.0)])
    assert u == pytest.approx((0.5, 0.5), abs=1e-12)


rows_strategy = st.lists(
    st.tuples(
        st.floats(0, 2 * math.pi),
        st.floats(-0.5, 0.5),
    ),
    min_size=1,
    max_size=20,
)


@settings(max_examples=400, deadline=None)
@given(rows_strategy, st.floats(-1, 1), st.floats(-1, 1))
def test_every_returned_command_satisfies_every_row_and_is_optimal(raw, ux, uy):
    rows = [(math.cos(phi), math.sin(phi), b) for phi, b in raw]
    u = solve_exact(ux, uy, rows)
    if u is None:
        return
    assert violation(u, rows) <= 1e-9
    # Optimality (KKT): u_hat - u is a non-negative combination of the active normals; checked
    # as "no feasible point is closer", sampled around u.
    d0 = math.dist(u, (ux, uy))
    for k in range(16):
        phi = 2 * math.pi * k / 16
        for r in (1e-4, 1e-2):
            cand = (u[0] + r * math.cos(phi), u[1] + r * math.sin(phi))
            if violation(cand, rows) <= 0.0:
                assert math.dist(cand, (ux, uy)) >= d0 - 1e-9


@settings(max_examples=300, deadline=None)
@given(rows_strategy, rows_strategy, st.floats(-0.3, 0.3), st.floats(-0.3, 0.3))
def test_relaxation_keeps_hard_rows_and_uses_the_smallest_slack(hard_raw, soft_raw, ux, uy):
    limits = [(math.cos(a), math.sin(a), 0.22) for a in (0, math.pi / 2, math.pi, 3 * math.pi / 2)]
    hard = [(math.cos(phi), math.sin(phi), abs(b) * 0.3) for phi, b in hard_raw]  # 0 feasible
    soft = [(math.cos(phi), math.sin(phi), b) for phi, b in soft_raw]
    res = solve_cbf_qp(ux, uy, limits, hard, soft)
    u = (res.ux, res.uy)
    assert violation(u, limits + hard) <= 1e-8
    if res.status == STATUS_OK:
        assert res.slack == 0.0 and violation(u, soft) <= 1e-8
    else:
        assert res.status == STATUS_RELAXED
        assert violation(u, soft) <= res.slack + 1e-8
        # Minimal: a slightly smaller slack is infeasible (checked with an independent backend).
        # A near-antiparallel pair of rows makes a thin wedge, where a backend's row tolerance
        # (1e-6) moves a point by 1e-6 / sin(angle): allow that much.
        rows = limits + hard
        sines = [abs(a[0] * b[1] - a[1] * b[0]) for i, a in enumerate(hard) for b in hard[i + 1:]]
        margin = max(1e-4, 1e-5 / max(min(sines, default=1.0), 1e-12))
        daqp = qpsolvers_solver("daqp")
        smaller = [(ax, ay, b + res.slack - margin) for ax, ay, b in soft]
        assert res.slack < margin or daqp(ux, uy, rows + smaller) is None


def test_infeasible_hard_rows_give_the_least_risk_command_and_say_so():
    limits = [(1.0, 0.0, 0.2), (-1.0, 0.0, 0.2), (0.0, 1.0, 0.2), (0.0, -1.0, 0.2)]
    hard = [(1.0, 0.0, -0.5), (-1.0, 0.0, -0.5)]  # x <= -0.5 and x >= 0.5: impossible
    res = solve_cbf_qp(0.1, 0.1, limits, hard, [])
    assert res.status == STATUS_FALLBACK and not res.solved
    assert violation((res.ux, res.uy), limits) <= FEAS_TOL
    # Both hard rows violated equally (0.5 each) is the least risk: x = 0.
    assert res.ux == pytest.approx(0.0, abs=1e-6)
    assert res.slack == pytest.approx(0.5, abs=1e-6)


def test_unknown_solver_name_is_a_clear_error():
    with pytest.raises(ValueError, match="solver: 'nope'"):
        make_solver("nope")
    assert make_solver("exact") is solve_exact

"""A unicycle's turn rate capped near things (:func:`agent.unicycle.near_turn_cap`): where the
full turn rate's sampling margin would be more than :data:`agent.unicycle.NEAR_MARGIN` (0.40 m
at gamma 0.05 and dt 0.1), Ds grows by that margin alone and the body still keeps Ds."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from agent import control, unicycle
from agent.control import Controller, ControlParams, StepInput
from geometry.shapes import segment
from scenario import load_scenario

SCENARIOS = Path(__file__).parent / "scenarios"
L, W, DT, GAMMA = 0.05, 2.84, 0.1, 0.05  # a TurtleBot at 10 Hz, obstacle gamma 0.05


def _params(dt: float = DT, gamma: float = GAMMA) -> ControlParams:
    return ControlParams(unicycle=True, lookahead=L, max_turn_rate=W, max_speed=0.22,
                         period=dt, gamma_obstacle=gamma, method="thesis")


def test_the_margin_is_the_full_one_where_small_and_near_margin_where_the_cap_holds_it():
    full = 0.5 * L * W ** 2 * 0.05 / 1.0  # 20 Hz, gamma 1: 1 cm, the number as before
    assert _params(0.05, 1.0).sampling_margin == full and not _params(0.05, 1.0).turn_capped
    assert _params(0.05, 1.0).load_sampling_margin == full
    capped = _params()
    assert unicycle.full_sampling_margin(L, W, DT, GAMMA) == pytest.approx(0.403, abs=1e-3)
    assert capped.sampling_margin == unicycle.NEAR_MARGIN and capped.turn_capped
    # the load rows (at the unicycle gamma 1) need v omega dt^2 / 2 / (1 dt) = 3.1 cm here
    assert capped.load_sampling_margin == pytest.approx(0.5 * 0.22 * W * DT, rel=1e-9)
    assert ControlParams(unicycle=False, period=DT, gamma_obstacle=GAMMA).sampling_margin == 0.0


def test_the_cap_binds_only_near_the_margins_edge_and_never_below_its_fixed_point():
    m = unicycle.NEAR_MARGIN
    cap = [unicycle.near_turn_cap(h, m, L, DT, GAMMA, W) for h in (1.0, 0.0, -0.02, -0.029,
                                                                     -m, -0.1)]
    assert cap[0] == cap[1] == cap[2] == W  # beyond the boundary and 2 cm inside: the full rate
    assert cap[3] < W and cap == sorted(cap, reverse=True)
    floor = math.sqrt(2.0 * GAMMA * DT * m / L) / DT  # 0.77 rad/s: its error's fixed point is m
    assert cap[4] == pytest.approx(floor) and cap[5] == pytest.approx(floor)
    assert unicycle.point_error(L, floor, DT) / (GAMMA * DT) == pytest.approx(m)


def _worst_sink(turn_rate) -> float:
    """The lowest h of h+ = (1 - gamma dt) h - e(omega(h)) from the boundary over 60 s: every
    period turning as fast as allowed the way that takes the point inwards."""
    h = low = 0.0
    for _ in range(600):
        h = (1.0 - GAMMA * DT) * h - unicycle.point_error(L, turn_rate(h), DT)
        low = min(low, h)
    return low


def test_the_worst_sink_stays_within_the_margin_with_the_cap_and_not_without():
    m = unicycle.NEAR_MARGIN
    assert _worst_sink(lambda h: unicycle.near_turn_cap(h, m, L, DT, GAMMA, W)) >= -m - 1e-12
    assert _worst_sink(lambda h: W) < -0.3  # towards the full margin, 0.40 m


WALL = segment("wall", (-10.0, 0.0), (10.0, 0.0), 0.15)


def _turn_near_the_wall(clearance: float) -> float:
    """The turn rate a unicycle facing away from a wall commands when asked to move its point
    sideways at full speed, its point ``clearance`` beyond its rows' boundary (Ds grown by the
    look-ahead and the margin)."""
    p = _params()
    point_y = 0.15 + L + p.sampling_margin + clearance
    res = Controller(p).step(StepInput((0.0, point_y - L, math.pi / 2), (-5.0, point_y - L),
                                       shapes=(WALL,)))
    assert res.status == "ok"
    return res.omega


def test_near_the_margins_edge_the_command_turns_no_faster_than_the_cap():
    m = unicycle.NEAR_MARGIN
    assert _turn_near_the_wall(0.05) == pytest.approx(W)  # the full rate beyond the boundary
    for inside in (-0.0285, -0.0299):
        cap = unicycle.near_turn_cap(inside, m, L, DT, GAMMA, W)
        assert cap < W and _turn_near_the_wall(inside) == pytest.approx(cap, rel=1e-6)


def test_without_the_cap_the_command_turns_at_the_full_rate_there(monkeypatch):
    monkeypatch.setattr(control, "near_limit_rows", lambda *args: None)
    assert _turn_near_the_wall(-0.029) == pytest.approx(W)


@pytest.mark.parametrize("name", ["door-gamma005-line-unicycle-dt01",
                                  "door-gamma005-pair-unicycle-dt01"])
def test_the_door_files_at_dt_0_1_keep_the_stated_margin(name):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    p = ControlParams.from_scenario(s)
    assert s.dt == 0.1 and p.turn_capped and p.sampling_margin == unicycle.NEAR_MARGIN

"""The view range (issue 18): a formation hands its members only the other formations within
``leader.role.VIEW_RANGE`` of its ellipse, and the control step's inputs leave out the same ones,
so that a tick's cost grows with the neighbourhood, not the fleet. Sound because nothing farther
can act on a member: its ellipse row cannot bind and no formation-level rule reaches that far."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import control
from agent.barriers import ellipse_row
from agent.control import Stall
from agent.inputs import step_inputs
from geometry.ellipse import Ellipse, within_reach
from leader.role import VIEW_RANGE

unit = st.floats(-1.0, 1.0)
angle = st.floats(-math.pi, math.pi)


WIDE = st.floats(-20.0, 20.0)


@st.composite
def ellipses(draw, cx=WIDE, speed=0.5, turn=1.0, tip=0.5) -> Ellipse:
    """A formation's ellipse: its centroid at up to ``speed`` [m/s], turning at up to ``turn``
    rad/s with its tip (a |alpha'|) at up to ``tip`` [m/s]. An ellipse turns with its members (the
    least-squares rotation of their positions), whose speed limit bounds the tip's speed to
    about theirs; a 2 m by 0.25 m ellipse turning at 1 rad/s (its tip at 2 m/s) made a row
    4 m out of view bind (hypothesis found it: b = -1.02)."""
    a = draw(st.floats(0.2, 3.0))
    b = draw(st.floats(0.1, 1.0)) * a
    r, th = draw(st.floats(0.0, speed)), draw(angle)
    spin = min(turn, tip / a)
    return Ellipse(draw(cx), draw(st.floats(-20.0, 20.0)), draw(angle), a, b,
                   r * math.cos(th), r * math.sin(th), draw(st.floats(-spin, spin)))


@settings(max_examples=400, deadline=None)
@given(ellipses(), ellipses(speed=0.0), st.floats(0.0, 1.0), angle, st.floats(-0.5, 0.5),
       st.floats(0.0, 5.0), st.floats(0.2, 5.0))
def test_the_row_of_a_formation_beyond_the_view_range_holds_for_every_command_a_member_can_give(
        own, other, rin, th_out, off_line, extra, gamma):
    """A member (its control point within its ellipse's semi-major axis of the centre, near the
    line to the other formation) facing a formation out of view that comes straight at it at
    0.5 m/s, turning at up to 1 rad/s: the ellipse row (A.3 (19), normalised: |(ax, ay)| = 1) is
    met by every command up to 0.5 m/s (its bound is at least 0.5), so leaving it out changes
    no solution."""
    d = VIEW_RANGE + own.a + other.a + extra  # out of view by ``extra``
    cx, cy = own.cx + d * math.cos(th_out), own.cy + d * math.sin(th_out)
    assert not within_reach(own, cx, cy, other.a, VIEW_RANGE - 1e-9)
    px = own.cx + rin * own.a * math.cos(th_out + off_line)
    py = own.cy + rin * own.a * math.sin(th_out + off_line)
    r = math.hypot(px - cx, py - cy)
    other = other._replace(cx=cx, cy=cy, vx=0.5 * (px - cx) / r, vy=0.5 * (py - cy) / r)
    _h, (ax, ay, b) = ellipse_row(px, py, other, gamma)
    assert math.hypot(ax, ay) == pytest.approx(1.0)
    assert b >= 0.5


@settings(max_examples=200, deadline=None)
@given(ellipses(cx=st.floats(-2.0, 2.0)), st.lists(ellipses(), min_size=0, max_size=8))
def test_the_step_inputs_keep_exactly_the_formations_the_leader_hands_on(own, others):
    named = [(f"F{k}", e) for k, e in enumerate(others)]
    inputs = step_inputs((), own, "OWN", (own.cx, own.cy), named, Stall(), 0.05)
    kept = [name for name, e in named if within_reach(own, e.cx, e.cy, e.a, VIEW_RANGE)]
    assert inputs.view is not None
    assert list(inputs.view.other_names) == kept
    assert inputs.hazards == [e for name, e in named if name in kept]


def test_every_formation_level_rule_looks_no_farther_than_the_view_range():
    assert control.TUNING.tiebreak.range < VIEW_RANGE

"""leader.listen: a leader hears at full rate only the formations that may come into view, the
rest through their once-a-second beacon (issue 18), and a formation that cannot be in view does
not stop it however stale it is."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agent.leader_step import newest
from formation.cli import main
from geometry.ellipse import Ellipse, within_reach
from leader.listen import (
    BEACON_PERIOD,
    LISTEN_HYSTERESIS,
    LISTEN_MARGIN,
    QUIET_MAX_S,
    beacon_due,
    grown_gap,
    hears,
    quiet_until,
)
from leader.role import VIEW_RANGE
from wire.payloads import EllipseMsg

ROOT = Path(__file__).resolve().parent.parent

coord = st.floats(-30.0, 30.0)
axis = st.floats(0.1, 2.0)
angle = st.floats(-math.pi, math.pi)


def msg(fid: str, cx: float, cy: float, a: float, stamp: float = 0.0) -> EllipseMsg:
    return EllipseMsg(fid, cx, cy, 0.0, a, a / 2, 0.0, 0.0, 0.0, stamp)


SUBSCRIBE_S = 0.5  # [s] ten ticks at 20 Hz: far more than declaring a subscriber and the next tick


@settings(max_examples=300, deadline=None)
@given(ox=coord, oy=coord, oa=axis, d=st.floats(0.0, 20.0), th=angle, a=axis,
       age=st.floats(0.0, 5.0), speed=st.floats(0.05, 2.0), frac=st.floats(0.0, 1.0),
       listening=st.booleans())
def test_a_formation_not_listened_to_cannot_reach_the_view_before_it_is_heard_again(
        ox, oy, oa, d, th, a, age, speed, frac, listening):
    own = Ellipse(ox, oy, 0.0, oa, oa / 2)
    cx, cy = ox + d * math.cos(th), oy + d * math.sin(th)
    m = msg("X", cx, cy, a)
    assume(not hears(grown_gap(own, m, speed * age), listening))
    # the worst case: since its message the other formation drove straight at this one for
    # age + tau seconds, and this one straight at it for tau, at top speed (up to 2 m/s); for
    # tau up to SUBSCRIBE_S (a subscription in effect) the other is still out of view
    tau = frac * SUBSCRIBE_S
    far, near = speed * (age + tau), speed * tau
    moved = Ellipse(ox + near * math.cos(th), oy + near * math.sin(th), 0.0, oa, oa / 2)
    assert not within_reach(moved, cx - far * math.cos(th), cy - far * math.sin(th), a,
                            VIEW_RANGE)


@settings(max_examples=300, deadline=None)
@given(ox=coord, oy=coord, oa=axis, excess=st.floats(1e-6, 3.0), th=angle, a=axis,
       age=st.floats(0.0, 5.0), speed=st.floats(0.05, 2.0), frac=st.floats(0.0, 1.0))
def test_a_far_formation_left_unlooked_at_until_quiet_until_stays_beyond_the_listening_range(
        ox, oy, oa, excess, th, a, age, speed, frac):
    own = Ellipse(ox, oy, 0.0, oa, oa / 2)
    d = oa + a + speed * age + VIEW_RANGE + LISTEN_MARGIN + excess  # grown gap: limit + excess
    m = msg("X", ox + d * math.cos(th), oy + d * math.sin(th), a)
    gap = grown_gap(own, m, speed * age)
    assert not hears(gap, False)
    until = quiet_until(10.0, gap, speed)
    assert 10.0 < until <= 10.0 + QUIET_MAX_S
    # the worst case up to that time: this formation drove straight at the other, and the
    # other's message is older by as much (it grows): still not heard, so nothing was missed
    tau = frac * (until - 10.0)
    moved = Ellipse(ox + speed * tau * math.cos(th), oy + speed * tau * math.sin(th), 0.0, oa,
                    oa / 2)
    assert not hears(grown_gap(moved, m, speed * (age + tau)) + 1e-9, False)  # at until: on it


def test_a_formation_on_the_edge_is_let_go_only_past_the_hysteresis_and_age_brings_it_back():
    own = Ellipse(0.0, 0.0, 0.0, 0.5, 0.25)
    edge = VIEW_RANGE + LISTEN_MARGIN + 0.5 * LISTEN_HYSTERESIS  # between the two limits
    near = grown_gap(own, msg("near", 1.0 + edge, 0.0, 0.5), 0.0)
    assert near == pytest.approx(edge)
    assert not hears(near, False) and hears(near, True)
    far = msg("far", 1.0 + VIEW_RANGE + LISTEN_MARGIN + LISTEN_HYSTERESIS + 0.1, 0.0, 0.5)
    assert not hears(grown_gap(own, far, 0.0), True)
    # an old message grows with its age: 1 s at 2 m/s brings "far" (gap 7.1 m) back in
    assert hears(grown_gap(own, far, 2.0 * 1.0), False)


def test_a_beacon_goes_out_once_a_period_and_again_when_the_clock_went_back():
    assert beacon_due(5.0, None)
    assert not beacon_due(5.0 + 0.5 * BEACON_PERIOD, 5.0)
    assert beacon_due(5.0 + BEACON_PERIOD, 5.0)
    assert beacon_due(4.0, 5.0)


def test_the_newest_of_ellipse_and_beacon_counts_and_a_message_naming_another_formation_does_not():
    old, new = (msg("B", 1.0, 0.0, 0.5, stamp=1.0), 0.0), (msg("B", 2.0, 0.0, 0.5, stamp=2.0), 0.0)
    assert newest("B", old, new) is new
    assert newest("B", new, old) is new
    assert newest("B", None, old) is old
    assert newest("B", (msg("C", 9.0, 9.0, 0.5, stamp=3.0), 0.0), old) is old
    assert newest("B", None, None) is None


@pytest.mark.integration
def test_in_real_time_leaders_hear_far_formations_only_by_beacon_and_a_dead_far_one_stops_nobody(
        tmp_path):
    # A and B pass each other 1.2 m apart after starting 14 m apart; C parks 40 m away and
    # both its agents die at 2 s (no successor left). Before leader.listen, C's ellipse went
    # stale and, 10 s (ellipse_hold) later, A and B stopped short of their goals.
    out = tmp_path / "out"
    assert main(["run", str(ROOT / "tests" / "scenarios" / "listen-pass.yaml"), "--out", str(out),
                 "--realtime", "--quiet", "--no-plots", "--kill", "c1@2", "--kill", "c2@2"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["collisions"] == 0 and s["all_reached"] is True
    for leader in ("a1", "b1"):
        st_ = json.loads((out / "agents" / f"{leader}.json").read_text())
        # heard the other every tick only from shortly before passing to shortly after
        assert st_["listen_changes"] >= 2
        assert st_["listening"] == []
        assert math.isfinite(st_["min_h"]["formations"])  # the other was in view, with rows
        # full rate only while near: well under one ellipse per tick from each of 2 others
        assert st_["received"]["ellipse"] < 0.5 * 2 * st_["ticks"]
        assert st_["received"]["beacon"] >= 10
        assert st_["inflated"] == 0
        assert st_["stale_why"].get("ellipse", 0) <= 2  # start-up only

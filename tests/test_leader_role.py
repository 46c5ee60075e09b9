"""The leader role: its ellipse is :func:`leader.ellipse.estimate` on the members' states, and
its ``others`` message holds the other leaders' ellipses and its own."""

from __future__ import annotations

from pathlib import Path

import pytest
from numpy.testing import assert_allclose

from agent.config import build_agent_configs
from agent.unicycle import control_point
from leader.ellipse import Ellipse, estimate, reference_shape
from leader.role import VIEW_RANGE, LeaderRole, ellipse_to_msg, msg_to_ellipse
from scenario import formation_axes, load_scenario
from wire import keys

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "thesis-5.2.2.yaml"


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(SCENARIO)


@pytest.fixture(scope="module")
def role(scenario) -> LeaderRole:
    cfg = build_agent_configs(scenario)["r2"]
    return LeaderRole(cfg.formation, cfg.leader)


def moved_states(scenario) -> dict[str, tuple[float, float, float, float, float]]:
    """F1 moved, rotated a little, with different velocities and headings per member."""
    f = scenario.formations[0]
    out = {}
    for k, r in enumerate(f.robots):
        x, y = control_point(*r.start, 0.0)
        out[r.id] = (x + 1.0 - 0.05 * y, y + 0.3 + 0.05 * x, 0.1 + 0.01 * k, -0.02 * k, 0.3 * k)
    return out


def test_the_role_estimates_the_same_ellipse_as_estimate_on_the_members_states(scenario, role):
    f = scenario.formations[0]
    states = moved_states(scenario)
    got = role.estimate(states)
    shape = reference_shape([control_point(*r.start, 0.0) for r in f.robots])
    want = estimate(shape, formation_axes(scenario, f), [s[:2] for s in states.values()],
                    [s[2:4] for s in states.values()], [s[4] for s in states.values()])
    assert got is not None
    assert_allclose(tuple(got[:8]), tuple(want[:8]), atol=1e-12)
    # the members' control points travel with it (the other formations' mirror rows)
    assert got.points == want.points == tuple(s[:2] for s in states.values())
    # and their headings (a formation of unicycles waits for its members to face its motion)
    assert got.headings == want.headings == tuple(s[4] for s in states.values())


def test_the_role_has_no_ellipse_while_a_member_is_missing(scenario, role):
    states = moved_states(scenario)
    del states["r3"]
    assert role.estimate(states) is None


def test_the_role_listens_to_exactly_the_other_leaders_ellipse_keys(role):
    assert set(role.other_keys) == {keys.ellipse_key(keys.DEFAULT_PREFIX, "F2")}
    assert role.ellipse_key == keys.ellipse_key(keys.DEFAULT_PREFIX, "F1")
    assert role.others_key == keys.others_key(keys.DEFAULT_PREFIX, "F1")


def test_others_holds_the_other_leaders_ellipses_and_the_own_one(scenario, role):
    own = role.estimate(moved_states(scenario))
    f2 = Ellipse(1.0, 0.3, 0.2, 0.6, 0.3, -0.1, 0.0, 0.01, ((1.2, 0.3), (0.8, 0.3)))
    received = {
        keys.ellipse_key(keys.DEFAULT_PREFIX, "F2"): ellipse_to_msg("F2", f2, 3.0),
        keys.ellipse_key(keys.DEFAULT_PREFIX, "F9"): ellipse_to_msg("F9", f2, 3.0),  # not ours
    }
    msg = role.others(own, received, 3.0)
    assert msg.formation == "F1"
    assert [m.formation for m in msg.ellipses] == ["F2"]
    assert msg_to_ellipse(msg.ellipses[0]) == f2
    assert msg.own is not None
    assert_allclose(tuple(msg_to_ellipse(msg.own)[:8]), tuple(own[:8]))
    assert msg_to_ellipse(msg.own).points == own.points and len(own.points) == 4
    assert msg_to_ellipse(msg.own).headings == own.headings and len(own.headings) == 4
    assert msg.stamp == 3.0


def test_others_carries_the_own_message_it_is_handed_as_it_is(scenario, role):
    own = role.estimate(moved_states(scenario))
    sent = ellipse_to_msg("F1", own, 2.0)  # the leader's published ellipse
    msg = role.others(own, {}, 2.0, sent)
    assert msg.own is sent
    assert msg == role.others(own, {}, 2.0)  # the same message it would build itself


def test_others_without_any_received_ellipse_still_carries_the_own_one(scenario, role):
    own = role.estimate(moved_states(scenario))
    msg = role.others(own, {}, 1.0)
    assert msg.ellipses == ()
    assert msg.own is not None


def test_settings_with_mismatched_offsets_are_rejected_naming_them(scenario):
    import dataclasses

    cfg = build_agent_configs(scenario)["r2"]
    bad = dataclasses.replace(cfg.leader, offsets=cfg.leader.offsets[:2])
    with pytest.raises(ValueError, match="offsets"):
        LeaderRole("F1", bad)


def test_others_leaves_out_a_formation_beyond_the_view_range_and_keeps_one_just_inside(scenario, role):
    own = role.estimate(moved_states(scenario))
    gap = VIEW_RANGE + own.a + 0.6  # centre distance at which F2's ellipse (a = 0.6) is just out
    key = keys.ellipse_key(keys.DEFAULT_PREFIX, "F2")
    far = Ellipse(own.cx + gap + 0.01, own.cy, 0.0, 0.6, 0.3)
    near = far._replace(cx=own.cx + gap - 0.01)
    assert role.others(own, {key: ellipse_to_msg("F2", far, 1.0)}, 1.0).ellipses == ()
    assert [m.formation for m in role.others(own, {key: ellipse_to_msg("F2", near, 1.0)},
                                             1.0).ellipses] == ["F2"]

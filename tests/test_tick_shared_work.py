"""The agent tick's cheap paths give what the plain ones give: the fixed-size messages' bytes and
builders, the verdicts and pushes shared by the agents of one process, the twist memo across
members of one shape, and the step's inputs made in one go."""

from __future__ import annotations

import math

import pytest
import zenoh
from zenoh.ext import UInt8, z_serialize

from agent import body
from agent.barriers import Obstacle
from agent.control import FormationView, Stall, shared_push, tiebreak_push
from agent.inbox import PairMemo, exact_take
from agent.inputs import step_inputs, waypoint_view
from geometry.ellipse import Ellipse
from wire.payloads import (
    Cmd,
    Pose,
    State,
    decode_cmd,
    decode_pose,
    decode_state,
    encode,
    encode_zbytes,
    new_cmd,
    new_pose,
    new_state,
)
from wire.traffic import Mailbox


@pytest.mark.parametrize(("msg", "fields"), [
    (Pose(1.5, -2.25, 0.3, 1e9 + 0.125), (1, 1.5, -2.25, 0.3, 1e9 + 0.125)),
    (State(0.1, 0.2, 0.03, -0.04, 7.5, 1.25), (2, 0.1, 0.2, 0.03, -0.04, 1.25, 7.5)),
    (State(0.1, 0.2, 0.03, -0.04, 7.5, 1.25, 0.02), (3, 0.1, 0.2, 0.03, -0.04, 1.25, 7.5, 0.02)),
    (Cmd(0.2, -0.5, 0.1, 0.05, 3.0), (1, 0.2, -0.5, 0.1, 0.05, 3.0)),
    (Cmd(0.2, -0.5, 0.1, 0.05, 3.0, 0.4, -0.3), (2, 0.2, -0.5, 0.1, 0.05, 0.4, -0.3, 3.0)),
])
def test_the_fixed_size_messages_are_the_bytes_of_the_zenoh_serialization(msg, fields):
    """Packed directly, a pose, state or command is byte for byte the serialization of its
    tuple (a u8 version, then f64s) and decodes back to itself."""
    wire = z_serialize((UInt8(fields[0]), *fields[1:])).to_bytes()
    assert encode(msg) == wire
    assert encode_zbytes(msg).to_bytes() == wire
    decode = {Pose: decode_pose, State: decode_state, Cmd: decode_cmd}[type(msg)]
    assert decode(wire) == msg


def test_the_builders_of_the_tick_messages_check_as_their_constructors_do():
    """Plain floats build the same message as the constructor; anything else goes through it
    (an int converted, a non-finite value refused with the field's name)."""
    assert new_pose(1.0, 2.0, 0.5, 9.0) == Pose(1.0, 2.0, 0.5, 9.0)
    assert new_state(1.0, 2.0, 0.1, 0.2, 9.0, 0.5) == State(1.0, 2.0, 0.1, 0.2, 9.0, 0.5)
    assert new_cmd(0.3, 0.1, 0.2, 0.2, 9.0) == Cmd(0.3, 0.1, 0.2, 0.2, 9.0)
    converted = new_state(1, 2.0, 0.1, 0.2, 9.0)
    assert converted == State(1.0, 2.0, 0.1, 0.2, 9.0) and type(converted.x) is float
    with pytest.raises(ValueError, match="uy"):
        new_state(1.0, 2.0, 0.1, math.nan, 9.0)
    with pytest.raises(ValueError, match="stamp"):
        new_cmd(0.0, 0.0, 0.0, 0.0, math.inf)
    with pytest.raises(ValueError, match="theta"):
        new_pose(0.0, 0.0, -math.inf, 1.0)


def test_a_pair_memo_answers_for_the_very_messages_only():
    """A verdict is remembered for the same objects; an equal but distinct message, or another
    number, is checked again."""
    calls = []

    def check(a, b, x):
        calls.append((a, b, x))
        return a[0] + b[0] <= x

    memo = PairMemo(check)
    a, b = [1.0], [2.0]
    assert memo(a, b, 3.0) is True
    assert memo(a, b, 3.0) is True
    assert len(calls) == 1
    assert memo(a, b, 2.5) is False
    assert memo([1.0], b, 3.0) is True
    assert len(calls) == 3


OWN = Ellipse(0.0, 0.0, 0.0, 0.6, 0.3, 0.1, 0.0, 0.0)
AHEAD = Ellipse(2.0, 0.02, 0.0, 0.6, 0.3, -0.1, 0.0, 0.0)


def test_the_shared_push_is_keep_rights_push_for_every_input():
    """The same push as :func:`tiebreak_push`, also after the hazards or obstacles change."""
    view = FormationView(OWN, 5.0, 0.0, "F1")
    obstacle = Obstacle(1.5, -0.3, 0.0, 0.0, 0.3)
    for hazards, obstacles in [([AHEAD], []), ([AHEAD], [obstacle]), ([], [obstacle]),
                               ([AHEAD._replace(cy=-0.5)], []), ([AHEAD], [])]:
        push = shared_push(view, hazards, obstacles, 0.22)
        assert push == tiebreak_push(view, hazards, obstacles, 0.22)
    assert shared_push(view, [AHEAD], [], 0.22) != (0.0, 0.0)


def test_members_of_one_shape_share_their_formations_twist():
    """Two members' footprints of one shape (different slots of it) have one shape object and
    get the very twist the first one solved; another goal is solved apart."""
    slots = ((-0.3, 0.0), (0.3, 0.0))
    first, second = body.Footprint(slots, 0.0, 0), body.Footprint(tuple(slots), 0.0, 1)
    assert first.shape is second.shape
    params = body.BodyParams(0.22, math.inf, 0.8, 0.5, 2.0, 0.05)
    own = Ellipse(0.0, 0.0, 0.0, 0.5, 0.2)
    snap = body.Snapshot((), (), ())
    memo = body.TwistMemo()
    one = memo.twist(first, own, (3.0, 0.0), snap, params)
    assert memo.twist(second, own, (3.0, 0.0), snap, params) is one
    assert one == body.formation_twist(second, own, (3.0, 0.0), snap, params)
    other = memo.twist(second, own, (0.0, 3.0), snap, params)
    assert other is not one and other == body.formation_twist(first, own, (0.0, 3.0), snap, params)


@pytest.mark.parametrize("leg", [(None, True), (0.7, True), (None, False), (-1.2, False)])
def test_the_step_inputs_made_in_one_go_hold_the_waypoint_and_the_rest(leg):
    """The view carries the waypoint as :func:`waypoint_view` puts it, and the other fields
    are the ones given."""
    made = step_inputs([(0.1, 0.2, 0.0, 0.0, 0.5)], OWN, "F1", (5.0, 0.0), [("F2", AHEAD)],
                       Stall(), 0.05, leg=leg, pose=(0.1, 0.2, 0.0), goal=(5.0, 0.0),
                       last_u=(0.1, 0.0))
    plain = step_inputs([(0.1, 0.2, 0.0, 0.0, 0.5)], OWN, "F1", (5.0, 0.0), [("F2", AHEAD)],
                        Stall(), 0.05)
    assert made.view == waypoint_view(plain.view, *leg)
    assert made._replace(view=plain.view) == plain._replace(pose=(0.1, 0.2, 0.0), goal=(5.0, 0.0),
                                                             last_u=(0.1, 0.0))


def test_an_exact_keys_take_stores_put_samples_under_its_key_and_ignores_deletes():
    """What ``Mailbox.callback`` stores, without reading the key back from each sample."""

    class Sample:
        def __init__(self, kind, payload):
            self.kind, self.payload = kind, zenoh.ZBytes(payload)
            self.key_expr = "fcbf/robot/r1/state"

    state = State(0.1, 0.2, 0.0, 0.0, 1.0)
    plain, fast = Mailbox(None, decode_state), Mailbox(None, decode_state)
    take = exact_take("fcbf/robot/r1/state", fast)
    for sample in (Sample(zenoh.SampleKind.PUT, encode(state)),
                   Sample(zenoh.SampleKind.DELETE, b"")):
        plain.callback(sample)
        take(sample)
    assert fast.latest("fcbf/robot/r1/state") == plain.latest("fcbf/robot/r1/state") == state
    assert fast.received == plain.received == 1

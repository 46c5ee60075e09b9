"""A formation parked at its goal: its leader says so on its ellipse (``parked``, wire version 4),
the members of the other formations read it from their ``others`` and never yield to it
(:func:`agent.control.yield_command`); the in-process simulator hands the same flag."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh import ZBytes
from zenoh.ext import UInt8, z_deserialize

from agent.control import TUNING, FormationView, yield_command
from agent.inputs import NOT_PARKED, parked_of, step_inputs, with_parked
from agent.params import Stall
from geometry.ellipse import Ellipse
from leader.navigation import Follower, at_goal
from leader.role import ellipse_to_msg
from scenario import load_scenario
from simulator import inprocess
from simulator.inprocess import FleetControl, SimOptions, simulate
from wire.payloads import (
    ELLIPSE_PARKED_VERSION,
    ELLIPSE_SIGMA_VERSION,
    DecodeError,
    EllipseMsg,
    Others,
    decode_ellipse,
    decode_others,
    encode,
)

SCENARIOS = Path(__file__).parent / "scenarios"


def _ellipse(name: str, parked: bool = False, sigma: float | None = None) -> EllipseMsg:
    return EllipseMsg(name, 1.0, 2.0, 0.1, 0.6, 0.3, 0.2, 0.0, 0.0, 4.5, ((1.0, 2.0), (1.5, 2.0)),
                      (0.0, 0.1), sigma, parked)


# --- the wire ---------------------------------------------------------------------------------


def test_a_parked_ellipse_round_trips_as_version_4_in_an_ellipse_and_in_others() -> None:
    for sigma in (None, 0.07):
        msg = _ellipse("F1", True, sigma)
        raw = encode(msg)
        assert raw[0] == ELLIPSE_PARKED_VERSION and raw[-1] == 1
        assert decode_ellipse(raw) == msg and decode_ellipse(raw).parked is True
    others = Others("F1", 4.5, (_ellipse("F2", True), _ellipse("F3", sigma=0.1)), _ellipse("F1"))
    raw = encode(others)
    assert raw[0] == ELLIPSE_PARKED_VERSION
    got = decode_others(raw)
    assert got == others
    assert [e.parked for e in got.ellipses] == [True, False] and got.own is not None \
        and got.own.parked is False
    assert [e.sigma for e in got.ellipses] == [None, 0.1]


def test_without_a_parked_ellipse_the_bytes_are_as_before() -> None:
    plain = _ellipse("F1")
    assert encode(plain)[0] == 2 and decode_ellipse(encode(plain)).parked is False
    assert encode(_ellipse("F1", sigma=0.1))[0] == ELLIPSE_SIGMA_VERSION
    others = Others("F1", 4.5, (_ellipse("F2"),), plain)
    assert encode(others)[0] == 2 and decode_others(encode(others)).ellipses[0].parked is False
    assert encode(dataclasses.replace(plain, parked=True)) != encode(plain)


_E4 = tuple[str, float, float, float, float, float, float, float, float, float,
            list[tuple[float, float]], list[float], list[float], UInt8]


def test_zenohs_own_deserializer_reads_a_version_4_ellipse() -> None:
    msg = _ellipse("F1", True, 0.05)
    got = z_deserialize(tuple[UInt8, str, float, float, float, float, float, float, float, float,
                              float, list[tuple[float, float]], list[float], list[float], UInt8],
                        ZBytes(encode(msg)))
    assert int(got[0]) == ELLIPSE_PARKED_VERSION and int(got[-1]) == 1 and got[-2] == [0.05]
    others = z_deserialize(tuple[UInt8, str, float, list[_E4], list[_E4]],
                           ZBytes(encode(Others("F2", 1.0, (msg,)))))
    assert int(others[3][0][-1]) == 1 and others[4] == []


@pytest.mark.parametrize("flag", [2, 255])
def test_a_parked_byte_other_than_0_or_1_is_refused(flag: int) -> None:
    raw = bytearray(encode(_ellipse("F1", True)))
    raw[-1] = flag
    with pytest.raises(DecodeError, match="parked"):
        decode_ellipse(bytes(raw))
    raw = bytearray(encode(Others("F2", 1.0, (), _ellipse("F2", True))))
    raw[-1] = flag  # the own ellipse's flag comes last
    with pytest.raises(DecodeError, match="parked"):
        decode_others(bytes(raw))
    with pytest.raises(ValueError, match="parked"):
        EllipseMsg("F1", 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, parked=1)  # type: ignore[arg-type]


def test_a_version_4_payload_cut_anywhere_raises_only_decode_error() -> None:
    for raw, decode in ((encode(_ellipse("F1", True, 0.2)), decode_ellipse),
                        (encode(Others("F2", 1.0, (_ellipse("F1", True),), _ellipse("F2"))),
                         decode_others)):
        for cut in range(len(raw)):
            with pytest.raises(DecodeError):
                decode(raw[:cut])
        with pytest.raises(DecodeError):
            decode(raw + b"\x00")


names = st.sampled_from(["A", "B", "C", "D", "E"])
floats = st.floats(-1e6, 1e6, allow_nan=False)


@st.composite
def parked_others(draw: st.DrawFn) -> Others:
    chosen = draw(st.lists(names, min_size=1, max_size=5, unique=True))
    ellipses = tuple(EllipseMsg(n, draw(floats), draw(floats), 0.0, 0.5, 0.3, 0.0, 0.0, 0.0,
                                draw(floats), parked=draw(st.booleans()),
                                sigma=draw(st.none() | st.floats(0.0, 1.0)))
                     for n in chosen[1:])
    return Others(chosen[0], 1.0, ellipses, None)


@settings(max_examples=100, deadline=None)
@given(msg=parked_others(), where=st.integers(0, 10_000), byte=st.integers(0, 255))
def test_a_corrupted_others_either_decodes_to_a_valid_message_or_raises_decode_error(
        msg: Others, where: int, byte: int) -> None:
    raw = encode(msg)
    assert decode_others(raw) == msg
    bad = bytearray(raw)
    bad[where % len(bad)] = byte
    try:
        got = decode_others(bytes(bad))
    except DecodeError:
        return
    assert all(type(e.parked) is bool for e in got.ellipses)


def test_members_read_the_parked_formations_of_their_others() -> None:
    msg = Others("F1", 1.0, (_ellipse("F2", True), _ellipse("F3")), _ellipse("F1", True))
    assert parked_of(msg) == frozenset({"F2"})  # its own ellipse is no other formation
    assert parked_of(decode_others(encode(msg))) == frozenset({"F2"})
    assert parked_of(Others("F1", 1.0, (_ellipse("F2"),))) is NOT_PARKED


def test_the_leader_marks_its_ellipse_parked_at_its_goal_on_the_last_leg_only() -> None:
    f = Follower("a1", (3.25, 0.0), (3.0, 0.0), ((1.0, 0.0), (3.0, 0.0)))
    assert not at_goal(f, (3.0, 0.0), 0.1)  # still on the first leg
    f.step(1.0, 0.0)  # the first waypoint passed
    assert f.index == 1
    assert at_goal(f, (3.05, 0.05), 0.1) and not at_goal(f, (3.2, 0.0), 0.1)
    e = Ellipse(3.0, 0.0, 0.0, 0.6, 0.3)
    assert ellipse_to_msg("A", e, 1.0, parked=True).parked
    assert not ellipse_to_msg("A", e, 1.0).parked


# --- the yield --------------------------------------------------------------------------------


def _view(name: str, cx: float, others: tuple[str, ...], parked: frozenset[str] = frozenset()
          ) -> FormationView:
    return FormationView(Ellipse(cx, 0.0, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0), 5.0, 0.0, name, others,
                         TUNING.stall.yield_time, parked=parked)


def test_a_jammed_formation_never_backs_away_from_one_parked_at_its_goal() -> None:
    e = _view("E", 0.0, ("F",)).own
    assert yield_command(_view("F", 1.3, ("E",)), [e], 0.22) is not None  # E moving: F backs off
    assert yield_command(_view("F", 1.3, ("E",), frozenset({"E"})), [e], 0.22) is None
    # beside a parked E and a moving D, it backs away from D alone
    d = Ellipse(1.3, 1.3, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0)
    back = yield_command(_view("F", 1.3, ("E", "D"), frozenset({"E"})), [e, d], 0.22)
    assert back is not None and back[0] == pytest.approx(0.0, abs=1e-12) and back[1] < 0.0


def test_the_parked_formations_join_the_view_of_the_step_inputs() -> None:
    own = Ellipse(1.3, 0.0, 0.0, 0.6, 0.3)
    inp = step_inputs((), own, "F", (5.0, 0.0), [("E", Ellipse(0.0, 0.0, 0.0, 0.6, 0.3))],
                      Stall(), 0.05)
    assert inp.view is not None and inp.view.parked == frozenset()
    got = with_parked(inp, frozenset({"E"})).view
    assert got is not None and got.parked == frozenset({"E"}) and got.other_names == ("E",)
    assert with_parked(inp, NOT_PARKED) is inp


def test_in_process_a_formation_at_its_goal_is_parked_and_one_on_its_way_is_not() -> None:
    s = load_scenario(SCENARIOS / "door-gamma005-four-unicycle.yaml")
    fc = FleetControl(s, SimOptions())
    tol = s.goal_tolerance + s.robot.control_offset
    lead = fc.replans.leader
    for name in ("E", "F"):  # every start is far from its goal: nobody parked yet
        f = fc.followers[lead[name]]
        f.index = len(f.route) - 1
    goal = fc.followers[lead["E"]].formation_goal
    at = {"E": Ellipse(goal[0] + 0.5 * tol, goal[1], 0.0, 0.6, 0.3),
          "F": Ellipse(0.0, 0.0, 0.0, 0.6, 0.3)}
    assert fc.parked(at) == frozenset({"E"})


# --- whole runs -------------------------------------------------------------------------------

CRAWL = SCENARIOS / "door-parked-crawl-unicycle.yaml"


def test_a_formation_crawling_beside_one_parked_at_its_goal_reaches_its_own(monkeypatch):
    s = load_scenario(CRAWL)
    run = simulate(s, SimOptions()).summary
    assert run["all_reached"] and run["collisions"] == 0
    assert run["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    # members that cannot tell a parked formation back away from it again and again
    monkeypatch.setattr(inprocess, "with_parked", lambda inputs, parked: inputs)
    blind = simulate(s, SimOptions()).summary
    assert not blind["all_reached"] and blind["collisions"] == 0


def test_a_lock_step_run_tells_parked_formations_as_the_simulation_does(tmp_path):
    """The leaders put ``parked`` on their ellipses over Zenoh and the members read it from
    their ``others``: the same robots.csv as the in-process simulation's."""
    from formation.cli import main

    assert main(["sim", str(CRAWL), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(CRAWL), "--out", str(tmp_path / "run"), "--quiet", "--no-plots"]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["mode"] == "multiprocess" and run["all_reached"] and run["collisions"] == 0
    assert (tmp_path / "run" / "robots.csv").read_text() == (tmp_path / "sim" / "robots.csv").read_text()

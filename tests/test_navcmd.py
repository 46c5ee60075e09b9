"""``formation goal`` / ``formation status`` against a leader stand-in on real Zenoh (loopback
router, explicit endpoints, multicast scouting off). The fleet itself: tests/test_hold.py."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
import zenoh

from formation.commands import goal as navcmd
from geometry.shapes import box
from leader.navigation import Follower, Navigator
from runtime.testing import RouterProcess
from wire import keys
from wire.navigation import decode_goal, encode_nav
from wire.payloads import DecodeError
from wire.zconf import ZenohSettings

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

SHELF = box("shelf", (2.0, 0.0), (0.6, 2.0), 0.0, 0.15)


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc


class LeaderStandIn:
    """A leader's goal and status handling on its own session (what the agent does, minus
    the control): accepts goals with a Navigator, answers status queries."""

    def __init__(self, endpoint: str, fid: str, quiet_s: float = 0.0,
                 fleet: tuple[str, ...] = ()) -> None:
        self.quiet_until = time.monotonic() + quiet_s  # a busy leader: no answers until then
        conf = ZenohSettings(mode="client", connect=(endpoint,)).to_config()
        self.session = zenoh.open(conf)
        self.nav = Navigator(fid, f"{fid}1", {f"{fid}1": (0.25, 0.0), f"{fid}2": (-0.25, 0.0)}, (0.0, 0.0),
                             fleet=fleet)
        self.follower = Follower(f"{fid}1", (0.25, 0.0), (0.0, 0.0))
        self.refused: list[str] = []
        self.lock = threading.Lock()
        self.subs = [
            self.session.declare_subscriber(keys.goal_key("warehouse", fid), self.on_goal),
            self.session.declare_queryable(keys.status_key("warehouse", fid), self.on_query),
        ]

    def on_goal(self, sample: zenoh.Sample) -> None:
        try:
            goal = decode_goal(sample.payload.to_bytes())
        except DecodeError:
            return
        with self.lock:
            why = self.nav.accept(goal, goal.stamp, (0.0, 0.0), [SHELF])
            if why is None:
                self.follower.adopt(self.nav.plan(goal.stamp))
            elif why != "the goal followed already":
                self.refused.append(why)

    def on_query(self, query: zenoh.Query) -> None:
        if time.monotonic() < self.quiet_until:
            return
        with self.lock:
            s = self.nav.status(self.follower, (0.0, 0.0), False, False, 1.0)
        query.reply(query.key_expr, encode_nav(s))

    def close(self) -> None:
        self.session.close()


def test_goal_exits_0_once_the_leader_shows_it_and_status_lists_every_formation(router, capsys):
    leaders = [LeaderStandIn(router.endpoint, "A"), LeaderStandIn(router.endpoint, "B")]
    try:
        rc = navcmd.main(["goal", "A", "4.0", "0.5", "--heading", "1.5", "--via", "1.0,2.0",
                          "--connect", router.endpoint, "--timeout", "10"])
        out = capsys.readouterr().out
        assert rc == 0, out
        assert "A: moving goal (4.000, 0.500) heading 1.500" in out and "waypoint 1/2" in out
        assert leaders[0].nav.route == ((1.0, 2.0), (4.0, 0.5))
        assert leaders[1].nav.goal == (0.0, 0.0)  # only A's leader got it
        assert navcmd.main(["status", "--connect", router.endpoint]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert [ln.split(":")[0] for ln in lines] == ["A", "B"]
    finally:
        for leader in leaders:
            leader.close()


def test_a_waypoint_may_carry_the_heading_the_formation_turns_to_there(router, capsys):
    leader = LeaderStandIn(router.endpoint, "H")
    try:
        rc = navcmd.main(["goal", "H", "4.0", "0.5", "--via", "1.0,2.0,0.5", "3.0,2.0",
                          "--connect", router.endpoint, "--timeout", "10"])
        assert rc == 0, capsys.readouterr().out
        assert leader.nav.route == ((1.0, 2.0), (3.0, 2.0), (4.0, 0.5))
        assert leader.nav.headings == (0.5, None, None)  # the goal keeps the formation's heading
        assert leader.nav.plan(1.0).headings == (0.5, None, None)
    finally:
        leader.close()


def test_a_goal_the_leader_refuses_exits_1_saying_why_from_its_status(router, capsys):
    leader = LeaderStandIn(router.endpoint, "C")
    try:
        # a long timeout: the refusal on the leader's status (version 2) ends the wait, not it
        rc = navcmd.main(["goal", "C", "2.0", "0.0", "--connect", router.endpoint, "--timeout", "60"])
        err = capsys.readouterr().err
        assert rc == 1
        assert "its leader refused it: the goal of 'C1' lies within the safe distance of box 'shelf'" in err
        assert "C: reached goal (0.000, 0.000)" in err and "1 goal(s) refused" in err
        assert "within the safe distance of box 'shelf'" in leader.refused[0]
    finally:
        leader.close()


def test_a_refusal_is_counted_once_when_the_leader_answers_late(router, capsys):
    # the leader answers no query for its first 1.5 s: the goal waits for its first answer,
    # else that answer counted this goal's refusal as an old one and the goal went again
    leader = LeaderStandIn(router.endpoint, "Q", quiet_s=1.5)
    try:
        rc = navcmd.main(["goal", "Q", "2.0", "0.0", "--connect", router.endpoint, "--timeout", "60"])
        err = capsys.readouterr().err
        assert rc == 1 and "its leader refused it" in err and "1 goal(s) refused" in err, err
        # the goal may go twice (a status asked for right after the put can be answered before
        # the goal arrives), but the leader counts it once
        assert leader.refused and leader.nav.rejected == 1
    finally:
        leader.close()


def test_a_goal_taken_but_unreachable_exits_1_with_the_leaders_reason(router, capsys):
    leader = LeaderStandIn(router.endpoint, "E")
    leader.nav.unreachable = "no route: the goal lies inside a closed room"  # as the planner says
    try:
        rc = navcmd.main(["goal", "E", "-2.0", "0.0", "--connect", router.endpoint, "--timeout", "60"])
        err = capsys.readouterr().err
        assert rc == 1
        assert leader.nav.goal == (-2.0, 0.0)  # taken: the status shows this goal...
        assert "no route reaches it" in err  # ...and why the formation will not get there
        assert "E: unreachable (no route: the goal lies inside a closed room) goal (-2.000, 0.000)" in err
    finally:
        leader.close()


def answering(endpoint: str, fid: str, within: float = 60.0) -> bool:
    """Whether the leader of ``fid`` answers a status query through the router within
    ``within`` seconds (its queryable reaches the router some time after it is declared; a
    query before that goes to no one: a fleet that is up answers, a stand-in just made may not)."""
    session = zenoh.open(ZenohSettings(mode="client", connect=(endpoint,)).to_config())
    try:
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            if any(s.formation == fid for s in navcmd.query_status(session, "warehouse", fid, 1.0)):
                return True
        return False
    finally:
        session.close()


def test_an_unknown_formation_is_refused_at_once_and_run_finds_the_endpoint(router, tmp_path, capsys):
    leader = LeaderStandIn(router.endpoint, "D")
    (tmp_path / "endpoint").write_text(router.endpoint + "\n")  # as `formation run --hold` writes
    try:
        assert answering(router.endpoint, "D")  # the fleet is up: its leaders answer
        # no --connect: the run folder's endpoint (no secure/ folder there: no credentials)
        rc = navcmd.main(["goal", "NOPE", "1.0", "0.5", "--run", str(tmp_path), "--timeout", "600"])
        err = capsys.readouterr().err
        assert rc == 2 and "no formation 'NOPE' in the fleet (known: " in err and "D" in err
        assert navcmd.main(["status", "--run", str(tmp_path)]) == 0
        assert "D: " in capsys.readouterr().out
    finally:
        leader.close()


def test_a_formation_whose_leader_has_not_answered_yet_is_known_from_another_leaders_status(
        router, capsys):
    # G's leader answers no query for its first 4 s (a fleet starting, or busy in lock-step):
    # F's status names every formation of the scenario, so G is waited for, not called unknown
    # (which 'known: F' was, from who answered within 2 s)
    f = LeaderStandIn(router.endpoint, "F", fleet=("G", "F"))
    g = LeaderStandIn(router.endpoint, "G", quiet_s=4.0, fleet=("F", "G"))
    try:
        assert answering(router.endpoint, "F")
        assert f.nav.status(f.follower, (0.0, 0.0), False, False, 1.0).fleet == ("F", "G")
        rc = navcmd.main(["goal", "G", "4.0", "0.5", "--connect", router.endpoint, "--timeout", "60"])
        captured = capsys.readouterr()
        assert rc == 0, captured.err
        assert "G: moving goal (4.000, 0.500)" in captured.out and g.nav.goal == (4.0, 0.5)
        rc = navcmd.main(["goal", "NOPE", "1.0", "0.5", "--connect", router.endpoint])
        assert rc == 2 and "no formation 'NOPE' in the fleet (known: F, G)" in capsys.readouterr().err
    finally:
        f.close()
        g.close()


@pytest.mark.parametrize("argv, message", [
    (["goal", "A", "1e308", "2"], "outside the world"),
    (["goal", "A", "1", "2", "--heading", "1e300"], "heading"),
    (["goal", "A", "1", "2", "--via", *["1,1"] * 64], "at most 63"),
    (["goal", "A", "1", "2", "--run", "/nonexistent-run"], "no endpoint file"),
    (["status", "--run", "/nonexistent-run"], "no endpoint file"),
    (["goal", "A", "1", "2", "--via", "1;2"], "--via '1;2': expected X,Y"),
    (["goal", "A/B", "1", "2"], "formation"),
    (["goal", "A", "1", "2", "--timeout", "0"], "--timeout must be a positive number"),
])
def test_bad_arguments_exit_2_naming_them(argv, message, capsys):
    assert navcmd.main(argv) == 2
    assert message in capsys.readouterr().err


def test_zenoh_errors_lose_the_place_in_zenohs_rust_sources():
    from wire.zconf import zenoh_words

    exc = RuntimeError("Unable to connect to any of [Single(tcp/127.0.0.1:5)]!  at "
                       "/root/.cargo/git/checkouts/zenoh-1/cc8/zenoh/src/net/runtime/orchestrator.rs:447.")
    assert zenoh_words(exc) == "Unable to connect to any of [Single(tcp/127.0.0.1:5)]!"
    assert zenoh_words(RuntimeError("Timeout!")) == "Timeout!"

"""A fleet robot whose agent is gone (its liveliness token went) is a body standing near its last
ellipse for every other leader, never dropped and never stopped for; a robot merely silent is
held inflated and then stopped for, as before (leader.succession, agent.leader_step)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from agent.clock import LockstepClock, RealtimeClock
from agent.config import build_agent_configs
from agent.faults import EPS
from agent.leader_step import Deaths, LeaderPart
from geometry.ellipse import Ellipse
from leader.succession import leader_token_key, standing_grow, stopping_distance, token_formation
from scenario import load_scenario
from wire import keys
from wire.payloads import EllipseMsg

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "lifelong" / "beam-spare-si.yaml"


def test_the_growth_is_top_speed_until_the_base_stops_plus_the_stopping_distance() -> None:
    assert standing_grow(0.2, 1.0, 0.05, 0.0) == pytest.approx(0.21)
    assert standing_grow(0.2, -1.0, 0.05, 0.1) == pytest.approx(0.11)  # never negative age
    assert stopping_distance(0.22, None, 0.05) == 0.0  # a velocity base stops at once
    assert stopping_distance(1.0, 2.0, 0.1) == pytest.approx(0.25 + 0.1)  # v^2 / 2a + v dt


def test_a_token_key_names_its_formation_and_nothing_else_does() -> None:
    assert token_formation("warehouse", leader_token_key("warehouse", "r1")) == "r1"
    assert token_formation("warehouse", "warehouse/formation/r1/ellipse") is None
    assert token_formation("warehouse", "other/formation/r1/leader") is None
    assert token_formation("warehouse", "warehouse/formation/a/b/leader") is None


@dataclass
class Sample:
    key_expr: str
    kind: Any


def test_deaths_hears_only_other_fleet_robots_and_fixes_the_first_use() -> None:
    d = Deaths("r2", ("r1", "r2", "r3"), "warehouse")
    gone = zenoh.SampleKind.DELETE
    d.on_token(Sample(leader_token_key("warehouse", "o1"), gone))  # a team's token: not a robot
    d.on_token(Sample(leader_token_key("warehouse", "r2"), gone))  # its own
    assert d.known_at("o1", 1.0) is None and d.known_at("r2", 1.0) is None and d.heard == 0
    d.on_token(Sample(leader_token_key("warehouse", "r1"), gone))
    assert d.known_at("r1", 3.0) == 3.0 and d.known_at("r1", 9.0) == 3.0 and d.heard == 1
    d.on_token(Sample(leader_token_key("warehouse", "r1"), zenoh.SampleKind.PUT))  # restarted
    assert d.known_at("r1", 9.0) is None


class Inbox:
    """The mailboxes a leader reads: the last ellipse of each formation."""

    def __init__(self) -> None:
        self.box: dict[str, tuple[EllipseMsg, float]] = {}

    def latest(self, cls: str, key: str) -> tuple[EllipseMsg, float] | None:
        return self.box.get(key) if cls == keys.ELLIPSE else None


def heard_at(part: LeaderPart, inbox: Inbox, now: float) -> None:
    """r3, far and fresh at ``now`` (only r1 is judged)."""
    key = keys.ellipse_key(part.cfg.prefix, "r3")
    inbox.box[key] = (EllipseMsg("r3", 20.0, 0.0, 0.0, 0.15, 0.15, 0.0, 0.0, 0.0, now), now)


def leader_of(rid: str, lockstep: bool = True) -> tuple[LeaderPart, Inbox]:
    cfg = build_agent_configs(load_scenario(SCENARIO))[rid]
    assert cfg.lifelong is not None and cfg.leader is not None  # a formation of one
    inbox = Inbox()
    clock = (LockstepClock(cfg.stale_after, 0.3, 0.0, rid, EPS) if lockstep
             else RealtimeClock(cfg.stale_after, cfg.control.offset))
    return LeaderPart(cfg, lockstep, 10.0, False, inbox, clock, {}), inbox  # type: ignore[arg-type]


def test_a_dead_robot_stands_grown_at_rest_for_good_and_a_silent_one_still_stops_the_leader() -> None:
    part, inbox = leader_of("r2")
    role = part.role
    assert role is not None and part.deaths is not None
    own = Ellipse(0.5, 0.0, 0.0, 0.2, 0.2)
    last = EllipseMsg("r1", 0.0, 0.6, 0.0, 0.15, 0.15, 0.2, 0.0, 0.0, 3.0)
    key = keys.ellipse_key(part.cfg.prefix, "r1")
    inbox.box[key] = (last, 3.0)
    # silent for 10.1 s, not known dead: beyond ellipse_hold, the tick is incomplete (stop)
    heard_at(part, inbox, 13.1)
    received, _, complete, _ = part.collect(role, own, 13.1, 13.1)
    assert not complete and key not in received
    part.deaths.hear("r1", alive=False)
    heard_at(part, inbox, 13.2)
    received, _, complete, inflated = part.collect(role, own, 13.2, 13.2)  # known at 13.2 s
    assert complete and not inflated
    body = received[key]
    dt, speed = part.cfg.period, part.cfg.control.max_speed
    grow = standing_grow(speed, 10.2, dt, 0.0)  # 10.2 s old when known
    assert body.a == pytest.approx(0.15 + grow) and body.b == pytest.approx(0.15 + grow)
    assert (body.cx, body.cy, body.vx, body.vy, body.alpha_rate) == (0.0, 0.6, 0.0, 0.0, 0.0)
    # an hour on: the same body, the tick complete (it is never dropped or stopped for)
    heard_at(part, inbox, 3613.2)
    received, _, complete, _ = part.collect(role, own, 3613.2, 3613.2)
    assert complete and received[key].a == pytest.approx(body.a)
    # back (a restarted agent): silent again, so stale, held and stopped for as before
    part.deaths.hear("r1", alive=True)
    heard_at(part, inbox, 3633.2)
    _, _, complete, _ = part.collect(role, own, 3633.2, 3633.2)
    assert not complete


def test_a_standing_body_out_of_view_is_left_out_but_known() -> None:
    part, inbox = leader_of("r2")
    role = part.role
    assert role is not None and part.deaths is not None
    key = keys.ellipse_key(part.cfg.prefix, "r1")
    inbox.box[key] = (EllipseMsg("r1", 40.0, 0.0, 0.0, 0.15, 0.15, 0.0, 0.0, 0.0, 3.0), 3.0)
    part.deaths.hear("r1", alive=False)
    heard_at(part, inbox, 60.0)
    received, _, complete, _ = part.collect(role, Ellipse(0.0, 0.0, 0.0, 0.2, 0.2), 60.0, 60.0)
    assert complete and key not in received


def test_a_silent_formation_beside_a_dead_one_is_still_held_inflated() -> None:
    part, inbox = leader_of("r2")
    role = part.role
    assert role is not None and part.deaths is not None
    for fid, cx in (("r1", 0.0), ("r3", 1.5)):
        inbox.box[keys.ellipse_key(part.cfg.prefix, fid)] = (
            EllipseMsg(fid, cx, 0.6, 0.0, 0.15, 0.15, 0.0, 0.0, 0.0, 3.0), 3.0)
    part.deaths.hear("r1", alive=False)
    received, _, complete, inflated = part.collect(role, Ellipse(0.5, 0.0, 0.0, 0.2, 0.2),
                                                   5.0, 5.0)
    assert complete and inflated  # r3 is 2 s stale: held, grown by its age
    r3 = received[keys.ellipse_key(part.cfg.prefix, "r3")]
    assert r3.a == pytest.approx(0.15 + part.cfg.control.max_speed * 2.0)


def test_in_real_time_the_body_grows_until_the_command_watchdog_stops_the_base() -> None:
    part, inbox = leader_of("r2", lockstep=False)
    role = part.role
    assert role is not None and part.deaths is not None
    key = keys.ellipse_key(part.cfg.prefix, "r1")
    inbox.box[key] = (EllipseMsg("r1", 0.0, 0.6, 0.0, 0.15, 0.15, 0.0, 0.0, 0.0, 100.0), 100.0)
    part.deaths.hear("r1", alive=False)
    heard_at(part, inbox, 112.0)
    received, _, complete, _ = part.collect(role, Ellipse(0.5, 0.0, 0.0, 0.2, 0.2), 112.0, None)
    cfg = part.cfg  # the token went after a 10 s lease: the body covers 12 s and the watchdog
    lag = cfg.stale_after + cfg.period
    assert complete and received[key].a == pytest.approx(0.15 + cfg.control.max_speed * (12.0 + lag))

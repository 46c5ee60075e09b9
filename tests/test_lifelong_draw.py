"""experiments.lifelong_draw: the halls of ``formation montecarlo --draw lifelong`` are valid
scenarios with stations, a fleet big enough for every load type and a servable stream, in runs
of at least 10 simulated minutes; the draw is a pure function of its seed."""

from __future__ import annotations

import dataclasses

import yaml

from experiments.lifelong_draw import (
    DURATION_S,
    MIN_ORDERS,
    RATE_PER_TEAM,
    STREAM_S,
    lifelong_problem,
    lifelong_scenario,
)
from experiments.montecarlo import DRAWS, LIFELONG, valid_scenario
from formation.cli import build_parser
from scenario import parse_scenario
from scenario.lifelong import SINK, SOURCE, STORE
from scenario.stream import plan

SEEDS = range(30)


def test_every_drawn_hall_is_a_valid_lifelong_scenario_with_a_servable_stream():
    redraws = 0
    for seed in SEEDS:
        d, s, sub = valid_scenario(seed, draw=LIFELONG)
        redraws += sub - seed * 1000
        life = s.lifelong
        assert life is not None and s.formations == ()
        assert lifelong_problem(s) is None
        assert s.duration >= 600.0 and life.stream is not None
        assert life.stream.until < s.duration  # time is left to finish the last orders
        kinds = {st.kind for st in life.stations}
        assert kinds == {SOURCE, SINK, STORE}
        assert max(t.team for t in life.load_types) <= len(life.fleet.robots)
        assert len(plan(life)) >= MIN_ORDERS
        again = parse_scenario(yaml.safe_dump(d, sort_keys=False))  # its file replays it
        assert again == s
    assert redraws < len(SEEDS)  # the draw rarely needs a second try


def test_the_draw_is_a_pure_function_of_its_seed_and_varies_with_it():
    assert lifelong_scenario(7) == lifelong_scenario(7)
    draws = [lifelong_scenario(seed) for seed in SEEDS]
    assert len({yaml.safe_dump(d) for d in draws}) == len(draws)
    assert {d["robot"]["model"] for d in draws} == {"single_integrator", "unicycle"}
    assert {tuple(sorted(d["load_types"])) for d in draws} == {
        ("pallet",), ("beam",), ("beam", "pallet")}
    names = {o["name"] for d in draws for o in d["obstacles"]}
    assert {"pillar", "forklift"} <= names
    assert any("stop_at" in o for d in draws for o in d["obstacles"])
    assert {len(d["fleet"]["robots"]) for d in draws} >= {4, 12}
    assert all(d["duration"] == DURATION_S for d in draws)


def test_the_draw_refuses_a_stream_that_serves_too_little_or_a_short_run():
    d = lifelong_scenario(3)
    s = parse_scenario(yaml.safe_dump(d))
    assert lifelong_problem(dataclasses.replace(s, duration=300.0)) == (
        "a run of 300 s, shorter than 10 minutes")
    d["order_stream"]["rate_per_min"] = 0.0
    quiet = parse_scenario(yaml.safe_dump(d))
    assert lifelong_problem(quiet) == f"the stream posts 0 servable orders, fewer than {MIN_ORDERS}"
    assert lifelong_problem(dataclasses.replace(s, lifelong=None)) == "no lifelong part"
    brief = dataclasses.replace(s.lifelong, stream=dataclasses.replace(s.lifelong.stream,
                                                                       until=300.0))
    assert lifelong_problem(dataclasses.replace(s, lifelong=brief)) == (
        "a stream of 300 s, shorter than 10 minutes")


def test_the_stream_runs_ten_minutes_at_a_rate_the_fleet_serves():
    for seed in SEEDS:
        d = lifelong_scenario(seed)
        team = max(t["team"] for t in d["load_types"].values())
        teams = len(d["fleet"]["robots"]) // team
        stream = d["order_stream"]
        assert stream["until"] == STREAM_S >= 600.0
        assert 0.0 < stream["rate_per_min"] <= min(1.2, RATE_PER_TEAM * teams) + 1e-4


def test_montecarlo_offers_the_lifelong_draw():
    assert LIFELONG in DRAWS
    ns = build_parser().parse_args(["montecarlo", "--draw", "lifelong", "--n", "2", "--out", "x"])
    assert ns.draw == "lifelong"

"""The lifelong part of a scenario (scenario.lifelong, scenario.lifelong_checks): what a file's
fleet, stations, load types, loads, orders and stream read as, and every refusal, each one line
naming the culprit, exit 2 from ``formation check``."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.cli import main
from scenario import ScenarioError, load_scenario, parse_scenario
from scenario.lifelong import SINK, SOURCE, STORE, default_slots, outline_at, slots_at
from scenario.stream import plan

ROOT = Path(__file__).resolve().parents[1]
LIFELONG_FILES = sorted((ROOT / "tests/scenarios").glob("lifelong-*.yaml")) + sorted(
    (ROOT / "scenarios").glob("lifelong-*.yaml"))

BASE = {
    "name": "hall",
    "duration": 600.0,
    "robot": {"max_speed": 0.22, "radius": 0.105},
    "fleet": {
        "robots": {"r1": {"start": [0.0, 0.0, 0.0]}, "r2": {"start": [0.5, 0.0]},
                   "r3": {"start": [1.0, 0.0]}, "r4": {"start": [1.5, 0.0]}},
        "parking": [[0.0, -1.0], [0.5, -1.0]],
    },
    "stations": {
        "dock_in": {"pose": [-4.0, 3.0, 0.0], "kind": "source"},
        "dock_out": {"pose": [-4.0, -3.0, 0.0], "kind": "sink", "dwell_s": 10},
        "rack_1": [4.0, 3.0, 1.5708],
        "rack_2": {"pose": [4.0, -3.0, 0.0], "kind": "store"},
    },
    "load_types": {"pallet": {"size": [0.8, 0.6], "team": 4},
                   "beam": {"size": [1.4, 0.3], "slots": [[-0.6, 0.0], [0.6, 0.0]]}},
    "loads": [{"name": "p1", "type": "pallet", "at": "rack_1"}],
    "orders": [{"id": "o1", "t": 0.0, "type": "pallet", "from": "dock_in", "to": "rack_2"},
               {"id": "o2", "t": 30.0, "load": "o1", "to": "dock_out", "priority": 2}],
    "order_stream": {"rate_per_min": 1.5, "seed": 5, "types": ["pallet", "beam"], "until": 600},
    "obstacles": [{"name": "wall-n", "segment": [[-6.0, 5.0], [6.0, 5.0]], "safe_distance": 0.15},
                  {"name": "shelf", "box": {"center": [0.0, 3.0], "size": [2.0, 0.6]},
                   "safe_distance": 0.15},
                  {"name": "pillar", "center": [0.0, -3.0], "safe_distance": 0.4}],
}

DELETE = object()


def variant(**changes) -> str:
    """BASE with ``a__b__0=value`` set (DELETE removes the key), as YAML text."""
    d = yaml.safe_load(yaml.safe_dump(BASE))
    for path, value in changes.items():
        node = d
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node[k]
        last = keys[-1]
        if value is DELETE:
            del node[int(last) if last.isdigit() else last]
        else:
            node[int(last) if last.isdigit() else last] = value
    return yaml.safe_dump(d)


def test_a_fleet_scenario_reads_as_the_model_says():
    s = parse_scenario(variant())
    life = s.lifelong
    assert life is not None and s.formations == ()
    assert life.fleet.robot_ids == ("r1", "r2", "r3", "r4")
    assert life.fleet.starts["r2"] == (0.5, 0.0, 0.0)  # [x, y]: heading 0
    assert life.fleet.parking == ((0.0, -1.0), (0.5, -1.0))
    assert (life.fleet.bid_window_s, life.fleet.bid_copies, life.fleet.lift_s) == (1.0, 3, 2.0)
    assert [(st.name, st.kind) for st in life.stations] == [
        ("dock_in", SOURCE), ("dock_out", SINK), ("rack_1", STORE), ("rack_2", STORE)]
    assert life.station("rack_1").pose == (4.0, 3.0, 1.5708)  # the shorthand is a store
    assert life.station("dock_out").dwell_s == 10.0
    pallet, beam = life.load_type("pallet"), life.load_type("beam")
    assert pallet.team == 4 and beam.team == 2 and beam.slots == ((-0.6, 0.0), (0.6, 0.0))
    assert life.loads[0].at == "rack_1" and life.type_of_load("o1") is pallet
    o1, o2 = life.orders
    assert (o1.type, o1.from_, o1.to, o1.load_name) == ("pallet", "dock_in", "rack_2", "o1")
    assert (o2.load, o2.from_, o2.to, o2.priority, o2.t) == ("o1", None, "dock_out", 2.0, 30.0)
    assert life.stream is not None and life.stream.types == ("pallet", "beam")
    assert (life.stream.rate_per_min, life.stream.seed, life.stream.until) == (1.5, 5, 600.0)


def test_a_file_without_lifelong_keys_has_no_lifelong_part():
    d = yaml.safe_load(variant())
    for key in ("fleet", "stations", "load_types", "loads", "orders", "order_stream"):
        del d[key]
    d["formations"] = [{"name": "A", "leader": "a1", "robots": {
        "a1": {"start": [0.0, 0.0], "goal": [1.0, 0.0]},
        "a2": {"start": [0.5, 0.0], "goal": [1.5, 0.0]}}, "edges": [["a1", "a2"]]}]
    assert parse_scenario(yaml.safe_dump(d)).lifelong is None


def test_default_slots_sit_at_the_long_axis_ends_or_the_corners_inset_by_the_radius():
    r = 0.1
    assert default_slots((1.0, 0.4), 2, r) == ((0.4, 0.0), (-0.4, 0.0))
    assert default_slots((0.4, 1.0), 2, r) == ((0.0, 0.4), (0.0, -0.4))  # long axis along y
    corners = default_slots((1.0, 0.6), 4, r)
    want = ((0.4, 0.2), (-0.4, 0.2), (-0.4, -0.2), (0.4, -0.2))
    assert [c for p in corners for c in p] == pytest.approx([c for p in want for c in p])
    for team in (3, 6):
        with pytest.raises(ValueError, match="no default slots"):
            default_slots((1.0, 1.0), team, r)
    with pytest.raises(ValueError, match="short side"):
        default_slots((1.0, 0.2), 4, r)


def test_outline_and_slots_turn_with_the_station():
    life = parse_scenario(variant()).lifelong
    assert life is not None
    pallet, rack = life.load_type("pallet"), life.station("rack_1")  # yaw pi/2 at (4, 3)
    xs = [p[0] for p in outline_at(pallet, rack.pose)]
    ys = [p[1] for p in outline_at(pallet, rack.pose)]
    assert max(xs) - min(xs) == pytest.approx(0.6, abs=1e-3)  # the 0.8 side now along y
    assert max(ys) - min(ys) == pytest.approx(0.8, abs=1e-3)
    for (x, y), (u, v) in zip(slots_at(pallet, rack.pose), pallet.slots, strict=True):
        assert math.hypot(x - 4.0, y - 3.0) == pytest.approx(math.hypot(u, v))


def test_formations_stay_required_without_a_fleet():
    with pytest.raises(ScenarioError, match="formations: missing"):
        parse_scenario("name: t\nobstacles: []\n")
    with pytest.raises(ScenarioError, match="formations: missing .at least one formation, or a fleet"):
        parse_scenario(variant(fleet=DELETE))
    formation = [{"name": "A", "leader": "a1", "robots": {
        "a1": {"start": [0.0, 1.0], "goal": [1.0, 1.0]},
        "a2": {"start": [0.5, 1.0], "goal": [1.5, 1.0]}}, "edges": [["a1", "a2"]]}]
    with pytest.raises(ScenarioError, match=r"^fleet: missing \(stations needs a fleet"):
        parse_scenario(variant(fleet=DELETE, formations=formation))


REFUSED = [
    ("unknown station in an order", variant(orders__0__to="rack_9"),
     "orders[0].to: unknown station 'rack_9'"),
    ("unknown source", variant(orders__0__from="dock_9"), "orders[0].from: unknown station"),
    ("unknown type in an order", variant(orders__0__type="crate"),
     "orders[0].type: unknown load type 'crate'"),
    ("unknown type of a load", variant(loads__0__type="crate"),
     "loads[0].type: unknown load type 'crate'"),
    ("unknown station of a load", variant(loads__0__at="rack_9"),
     "loads[0].at: unknown station 'rack_9'"),
    ("unknown load", variant(orders__1__load="p9"), "orders[1].load: unknown load 'p9'"),
    ("unknown type in the stream", variant(order_stream__types=["pallet", "crate"]),
     "order_stream.types[1]: unknown load type 'crate'"),
    ("a type needing more robots than the fleet has",
     variant(fleet__robots={"r1": {"start": [0.0, 0.0]}, "r2": {"start": [0.5, 0.0]},
                            "r3": {"start": [1.0, 0.0]}}),
     "load_types.pallet: needs a team of 4 robots, more than the fleet's 3"),
    ("a station's load over a shelf", variant(stations__rack_1=[0.0, 2.5, 0.0]),
     "stations.rack_1: a 'pallet' load resting there overlaps box 'shelf'"),
    ("a station's load over a wall", variant(stations__rack_1=[2.0, 4.9, 0.0]),
     "stations.rack_1: a 'pallet' load resting there overlaps segment 'wall-n'"),
    ("a slot inside a wall's safe distance", variant(stations__rack_1=[2.0, 4.69, 0.0]),
     "stations.rack_1: slot 0 of a 'pallet' load there is inside the safe distance of segment"),
    ("a station's load over a standing circle", variant(stations__rack_2__pose=[0.2, -3.0, 0.0]),
     "stations.rack_2: a 'pallet' load resting there overlaps obstacle 'pillar'"),
    ("two stations' loads overlapping", variant(stations__rack_2__pose=[4.5, 3.0, 0.0]),
     "stations.rack_1: a 'pallet' load resting there overlaps a 'pallet' load resting at "
     "station 'rack_2'"),
    ("a negative rate", variant(order_stream__rate_per_min=-1.0),
     "order_stream.rate_per_min: must not be negative"),
    ("an infinite rate", variant(order_stream__rate_per_min=math.inf),
     "order_stream.rate_per_min: must be finite"),
    ("a NaN rate", variant(order_stream__rate_per_min=math.nan),
     "order_stream.rate_per_min: must be finite"),
    ("a fleet robot named like a load", variant(fleet__robots__p1={"start": [2.0, 0.0]}),
     "loads[0].name: 'p1' is already the name of a robot of the fleet"),
    ("an order named like a robot", variant(orders__0__id="r1", orders__1__load="r1"),
     "orders[0].id: 'r1' is already the name of a robot of the fleet"),
    ("a fleet robot named like a formation's robot",
     variant(formations=[{"name": "A", "leader": "r1", "robots": {
         "r1": {"start": [0.0, 1.0], "goal": [1.0, 1.0]},
         "a2": {"start": [0.5, 1.0], "goal": [1.5, 1.0]}}, "edges": [["r1", "a2"]]}]),
     "fleet.robots.r1: 'r1' is already the name of a robot of formation 'A'"),
    ("a formation named like an order",
     variant(formations=[{"name": "o2", "leader": "a1", "robots": {
         "a1": {"start": [0.0, 1.0], "goal": [1.0, 1.0]},
         "a2": {"start": [0.5, 1.0], "goal": [1.5, 1.0]}}, "edges": [["a1", "a2"]]}]),
     "orders[1].id: 'o2' is already the name of formation 0"),
    ("an explicit order named like the stream's", variant(orders__1__id="s1"),
     "orders[1].id: 's1' is a name the order stream gives its orders"),
    ("an unknown station kind", variant(stations__rack_2__kind="shelf"),
     "stations.rack_2.kind: 'shelf' is not one of"),
    ("a dwell on a store", variant(stations__rack_2__dwell_s=5),
     "stations.rack_2.dwell_s: only a sink has a dwell"),
    ("a negative dwell", variant(stations__dock_out__dwell_s=-1),
     "stations.dock_out.dwell_s: must not be negative"),
    ("a non-finite pose", variant(stations__rack_2__pose=[4.0, math.nan, 0.0]),
     "stations.rack_2.pose[1]: must be finite"),
    ("two loads at one station",
     variant(loads=[{"name": "p1", "type": "pallet", "at": "rack_1"},
                    {"name": "p2", "type": "beam", "at": "rack_1"}]),
     "loads[1].at: load 'p1' already rests at 'rack_1'"),
    ("a load at a sink", variant(loads__0__at="dock_out"), "loads[0].at: 'dock_out' is a sink"),
    ("a new load from a store", variant(orders__0__from="rack_2"),
     "orders[0].from: 'rack_2' is a store, not a source"),
    ("an order to a source", variant(orders__0__to="dock_in"),
     "orders[0].to: 'dock_in' is a source"),
    ("an order with type and load", variant(orders__0__load="p1"),
     "orders[0]: needs exactly one of type"),
    ("a negative order time", variant(orders__1__t=-1.0), "orders[1].t: must not be negative"),
    ("a resting load's order from the wrong station",
     variant(orders__1__load="p1", orders__1__from="rack_2"),
     "orders[1].from: load 'p1' rests at 'rack_1', not at 'rack_2'"),
    ("a team without default slots", variant(load_types__pallet__team=3),
     "load_types.pallet.team: team 3 has no default slots"),
    ("a slot outside the outline", variant(load_types__beam__slots=[[-0.8, 0.0], [0.6, 0.0]]),
     "load_types.beam.slots[0]: (-0.8, 0) is outside the load's outline"),
    ("slots too close", variant(load_types__beam__slots=[[-0.1, 0.0], [0.1, 0.0]]),
     "load_types.beam: slots 0 and 1 are 0.200 m apart"),
    ("a fleet robot in a wall", variant(fleet__robots__r1__start=[0.0, 4.9, 0.0]),
     "fleet.robots.r1.start: 0.100 m from segment 'wall-n'"),
    ("two fleet robots on each other", variant(fleet__robots__r2__start=[0.1, 0.0]),
     "fleet.robots.r2: starts 0.100 m from fleet.robots.r1"),
    ("a fleet robot under a resting load", variant(fleet__robots__r1__start=[4.0, 3.0]),
     "fleet.robots.r1: starts under load 'p1' resting at 'rack_1'"),
    ("a parking spot inside a shelf", variant(fleet__parking=[[0.0, 3.0]]),
     "fleet.parking[0]: -0.300 m from box 'shelf', inside its safe distance"),
    ("a parking spot on a station", variant(fleet__parking=[[-4.0, -3.0]]),
     "fleet.parking[0]: a robot parked there overlaps a 'pallet' load at station 'dock_out'"),
    ("a stream with no store",
     variant(stations={"dock_in": {"pose": [-4.0, 3.0, 0.0], "kind": "source"}}, loads=[],
             orders=[]),
     "order_stream: no store to fill or empty"),
    ("an unknown fleet key", variant(fleet__size=4), "fleet: unknown key 'size'"),
]


@pytest.mark.parametrize("what,text,message", REFUSED, ids=[c[0] for c in REFUSED])
def test_every_refusal_is_one_line_naming_the_culprit(what, text, message):
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("what,text,message", REFUSED[:18], ids=[c[0] for c in REFUSED[:18]])
def test_check_refuses_with_exit_2_and_one_line(what, text, message, tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]


def test_check_says_what_the_lifelong_part_holds(tmp_path, capsys):
    path = tmp_path / "hall.yaml"
    path.write_text(variant(), encoding="utf-8")
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert ("fleet of 4 robots, 4 stations, 2 load types, 1 load, 2 orders and a stream"
            in out)


@pytest.mark.parametrize("path", LIFELONG_FILES, ids=[p.stem for p in LIFELONG_FILES])
def test_every_lifelong_scenario_passes_check(path, capsys):
    assert main(["check", str(path)]) == 0, capsys.readouterr().err


def _chained(s, life):
    ids = {o.id for o in life.orders}
    return any(o.load in ids for o in life.orders)


def _busy_source(s, life):
    starts = [o.from_ for o in life.orders if o.type is not None]
    return len(starts) != len(set(starts))


def _busy_destination(s, life):
    resting = {ld.at for ld in life.loads}
    return any(o.type is not None and o.to in resting for o in life.orders)


def _long_stream(s, life):
    return life.stream is not None and min(life.stream.until, s.duration) >= 1800.0 and bool(
        plan(life))


KINDS = {
    "chained": _chained,
    "retrieval to a sink": lambda s, life: any(
        o.type is None and life.station(o.to).kind == SINK for o in life.orders),
    "busy source": _busy_source,
    "busy destination": _busy_destination,
    "stream of 30 minutes": _long_stream,
    "parked forklift": lambda s, life: any(
        o.stop_at is not None and o.velocity != (0.0, 0.0) for o in s.obstacles),
    "pallets and beams": lambda s, life: {2, 4} <= {
        life.type_of_load(o.load_name).team for o in life.orders},
    "more orders than teams": lambda s, life: len(life.orders) > len(life.fleet.robots) // 2,
    "priority": lambda s, life: len({o.priority for o in life.orders}) > 1,
}


def test_the_lifelong_scenarios_cover_every_kind_the_acceptance_names():
    tests = [load_scenario(p) for p in LIFELONG_FILES if p.parent.parent.name == "tests"]
    assert len(tests) >= 12
    found = {s.robot.model for s in tests}
    for kind, test in KINDS.items():
        if any(test(s, s.lifelong) for s in tests):
            found.add(kind)
    assert found == {"single_integrator", "unicycle", "double_integrator", *KINDS}


def test_the_lifelong_example_in_the_docs_is_a_valid_scenario():
    import re

    text = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    example = next(block for block in re.findall(r"^```yaml\n(.*?)^```", text, re.M | re.S)
                   if block.startswith("fleet:"))
    s = parse_scenario("name: example\n" + example)
    assert s.lifelong is not None and [o.id for o in s.lifelong.orders] == ["o1", "o2"]
    assert s.lifelong.load_type("beam").slots == ((0.6, 0.0), (-0.6, 0.0))


def _paths(node, prefix=()):
    """Every path into a nested mapping or list (the node itself included)."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for k, v in enumerate(node):
            yield from _paths(v, (*prefix, k))


LIFELONG_PATHS = [p for key in ("fleet", "stations", "load_types", "loads", "orders",
                                "order_stream") for p in _paths(BASE[key], (key,))]
JUNK = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                 st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                 st.lists(st.floats(-10, 10), max_size=4),
                 st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(LIFELONG_PATHS), JUNK)
def test_any_value_anywhere_in_the_lifelong_part_loads_or_is_refused_in_one_line(path, junk):
    d = yaml.safe_load(yaml.safe_dump(BASE))
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = junk
    try:
        s = parse_scenario(yaml.safe_dump(d))
    except ScenarioError as exc:
        assert "\n" not in str(exc) and len(str(exc)) <= 400
    else:
        assert s.lifelong is not None

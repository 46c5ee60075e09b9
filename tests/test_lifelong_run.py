"""Lifelong operation in process (simulator.lifelong): each lifelong scenario runs and the load
really moves (tests/lifelong_checks.py); a member lost while carrying fails its order with the
load set down where it stands; the outputs' rows."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import pytest

from formation.cli import main
from leader import orders as lo
from scenario import load_scenario
from simulator.lifelong import Checks, LifelongOptions, collide, simulate_lifelong
from simulator.orders_out import ORDER_COLUMNS, order_rows, orders_block, write_order_files
from tests.lifelong_checks import check_all_delivered, check_safe, delivered_where_asked

HERE = Path(__file__).resolve().parent / "scenarios"
# the quick ones: a single order each, a few seconds
QUICK_STEMS = ("lifelong-one-pallet", "lifelong-beam-pair", "lifelong-forklift-cross-aisle",
               "lifelong-resting-bodies")
SHIPPED = Path(__file__).resolve().parent.parent / "scenarios" / "lifelong-warehouse.yaml"
# a drawn hall whose stream posts its last order too late to be delivered within the run
DRAWN_HALL = HERE / "lifelong" / "drawn-hall-unicycle.yaml"
ALL = [p for p in sorted((HERE / "lifelong").glob("*.yaml")) if p != DRAWN_HALL] + sorted(
    HERE.glob("lifelong-*.yaml")) + [SHIPPED]
QUICK = [p for p in ALL if p.stem.startswith("one-") or p.stem in QUICK_STEMS]
# streams of half an hour and more: minutes of CPU each, run with FORMATION_SLOW=1
HOURS = {"lifelong-stream-30min", "lifelong-stream-unicycle", "lifelong-warehouse"}
LONG = [pytest.param(p, id=p.stem, marks=pytest.mark.skipif(
            p.stem in HOURS and not os.environ.get("FORMATION_SLOW"),
            reason="a stream of half an hour or more: set FORMATION_SLOW=1"))
        for p in ALL if p not in QUICK]


@pytest.mark.parametrize("path", QUICK, ids=lambda p: p.stem)
def test_every_order_is_delivered_safely(path):
    check_all_delivered(simulate_lifelong(load_scenario(path)))


@pytest.mark.slow
@pytest.mark.parametrize("path", LONG)
def test_every_order_of_a_longer_scenario_is_delivered_safely(path):
    check_all_delivered(simulate_lifelong(load_scenario(path)))


@pytest.mark.slow
def test_in_a_drawn_hall_of_unicycles_every_order_is_delivered_or_still_open_none_stuck():
    # a gathering team that keeps its route at a change of teams must not hold on it for good
    result = simulate_lifelong(load_scenario(DRAWN_HALL))
    check_safe(result)
    orders = result.run.orders
    done = delivered_where_asked(result)
    still = [o.oid for o in orders.values() if not o.done]
    assert sorted(done + still) == sorted(orders), {o.oid: o.state for o in orders.values()}
    assert result.summary["orders"]["open"] == len(still)
    assert len(done) >= len(orders) - 1, {o.oid: o.state for o in orders.values()}


def test_a_member_lost_while_carrying_sets_the_load_down_where_it_stands():
    scenario = load_scenario(HERE / "lifelong" / "one-pallet-si.yaml")
    result = simulate_lifelong(scenario, life_options=LifelongOptions(kills=(("r2", 45.0),)))
    check_safe(result)
    order = result.run.orders["o1"]
    assert order.state == lo.FAILED and order.reason == "member lost: r2"
    assert order.t_lifted is not None and order.t_lifted < 45.0
    load = result.run.loads["o1"]
    assert load.state == "resting" and load.station == ""  # off any station, where it stood
    dock = scenario.lifelong.station("dock").pose
    assert math.dist(load.pose[:2], dock[:2]) > 0.5  # it had moved
    assert result.summary["orders"]["failed"] == 1


def test_the_greedy_baseline_serves_the_same_order():
    scenario = load_scenario(HERE / "lifelong" / "one-beam-unicycle.yaml")
    check_all_delivered(simulate_lifelong(scenario,
                                          life_options=LifelongOptions(allocator="greedy")))


def test_an_unknown_allocator_is_refused():
    scenario = load_scenario(HERE / "lifelong" / "one-beam-unicycle.yaml")
    with pytest.raises(ValueError, match="allocator"):
        simulate_lifelong(scenario, life_options=LifelongOptions(allocator="best"))


def delivered(oid: str, t0: float) -> lo.Order:
    order = lo.step(lo.Order(oid, "pallet", oid, "dock", "rack", fresh=True),
                    lo.Event(lo.POST, t0))
    for k, kind in enumerate((lo.ASSIGN, lo.JOIN, lo.GATHERED, lo.LIFTED, lo.ARRIVED,
                              lo.SET_DOWN)):
        order = lo.step(order, lo.Event(kind, t0 + 10.0 * (k + 1), ("r1", "r2")))
    return order


def test_orders_csv_rows_are_sorted_with_empty_cells_for_times_not_reached(tmp_path):
    waiting = lo.step(lo.Order("a", "beam", "a", "dock", "rack", fresh=True),
                      lo.Event(lo.POST, 5.0))
    write_order_files(tmp_path, [waiting, delivered("b", 0.0)], [], plots=False)
    with (tmp_path / "orders.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(ORDER_COLUMNS)
    assert [r["id"] for r in rows] == ["b", "a"]
    assert rows[0]["robots"] == "r1;r2" and rows[0]["state"] == "delivered"
    assert rows[1]["t_assigned"] == "" and rows[1]["state"] == "waiting"
    assert len(order_rows([waiting])) == 1


def test_the_orders_block_counts_and_rates():
    orders = [delivered("a", 0.0), delivered("b", 100.0)]
    block = orders_block(orders, {"a": 30.0, "b": 30.0}, 4, 3600.0, 3600.0)
    assert block["delivered"] == 2 and block["open"] == 0
    assert block["delivered_per_robot_hour"] == pytest.approx(0.5)
    assert block["latency_s"]["median"] == pytest.approx(60.0)
    assert block["service_efficiency"]["median"] == pytest.approx(30.0 / 50.0)
    assert block["idle_fraction"] == pytest.approx(0.75)


def test_a_member_lost_before_the_lift_returns_the_order_to_the_queue():
    scenario = load_scenario(HERE / "lifelong" / "beam-spare-si.yaml")
    result = simulate_lifelong(scenario, life_options=LifelongOptions(kills=(("r1", 3.0),)))
    check_all_delivered(result)  # the order waits again, and the other two deliver it
    order = result.run.orders["o1"]
    assert order.robots == ("r2", "r3") or order.robots == ("r3", "r2")
    # first assigned at the round of t = 1 s (r1 and r2), again at the loss (r2 and r3)
    assert order.t_assigned is not None and order.t_assigned >= 3.0
    assert result.run.loads["o1"].station == "rack"
    # the dead robot stands where it was killed, far from any slot
    assert math.dist(result.run.state[result.run.index["r1"]][:2], (0.0, 0.0)) < 0.7


def test_check_refuses_fixed_formations_beside_a_fleet_in_one_line(tmp_path, capsys):
    text = (HERE / "lifelong" / "beam-spare-si.yaml").read_text() + (
        "formations:\n"
        "  - name: A\n    leader: a1\n"
        "    robots: {a1: {start: [0.0, -2.0], goal: [1.0, -2.0]},"
        " a2: {start: [0.5, -2.0], goal: [1.5, -2.0]}}\n"
        "    edges: [[a1, a2]]\n")
    path = tmp_path / "beside.yaml"
    path.write_text(text)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "formations: 'A' beside a fleet" in err[0], err


def test_a_load_contact_is_one_collision_from_its_onset_to_its_release():
    checks = Checks()
    key = ("load", "o1", "r5")
    checks.contact(key, -0.01, {"t": 1.0, "a": "o1", "b": "r5", "kind": "load"})
    checks.contact(key, -0.03, {"t": 1.05, "a": "o1", "b": "r5", "kind": "load"})
    assert len(checks.events) == 1 and checks.events[0]["deepest_m"] == pytest.approx(-0.03)
    assert checks.events[0]["clearance_m"] == pytest.approx(-0.01)
    checks.release("resting_load", set())  # another kind: this contact stays open
    checks.contact(key, -0.02, {"t": 1.1, "a": "o1", "b": "r5", "kind": "load"})
    assert len(checks.events) == 1
    checks.release("load", set())  # apart: the next touch is a new collision
    checks.contact(key, -0.02, {"t": 2.0, "a": "o1", "b": "r5", "kind": "load"})
    assert len(checks.events) == 2


def test_the_loads_collisions_count_in_the_summary_in_time_order():
    summary = {"collisions": 1, "collision_log": [{"t": 5.0, "a": "r1", "b": "r2"}]}
    collide(summary, [{"t": 2.0, "a": "o1", "b": "wall", "kind": "load"},
                      {"t": 9.0, "a": "r3", "b": "p1", "kind": "resting_load"}])
    assert summary["collisions"] == 3
    assert [e["t"] for e in summary["collision_log"]] == [2.0, 5.0, 9.0]

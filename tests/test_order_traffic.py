"""Order traffic on its own line: ``comm`` of summary.json sums the order, bid and order-status
classes as ``orders`` per side, and ``formation commcost`` keeps them out of the topology's
counts, in their own columns."""

from __future__ import annotations

from experiments.commcost import crossing_scenario, measure_row
from scenario.load import scenario_from_dict
from simulator.summary import comm_summary
from wire import traffic

P = "warehouse"


def counted() -> traffic.Snapshot:
    counter = traffic.TrafficCounter(P)
    for _ in range(10):  # ten ticks of a pair: each member hears the other's state
        counter.count_recv(f"{P}/robot/f0r0/state", 49)
        counter.count_recv(f"{P}/robot/f0r1/state", 49)
    counter.count_put(f"{P}/order/o1", 60)
    for rid in ("f0r0", "f0r1"):
        counter.count_recv(f"{P}/order/o1", 60)
        counter.count_recv(f"{P}/order/o1/bid/{rid}", 70)
    counter.count_recv(f"{P}/order/o1/status", 80)
    return counter.snapshot()


def test_comm_counts_orders_on_their_own_line_and_not_in_the_topologys():
    comm = comm_summary(counted(), "reduced", 2, 0.5)
    assert comm["messages"] == 20  # the state deliveries only
    assert comm["orders"] == {"put": {"messages": 1, "bytes": 60},
                              "recv": {"messages": 5, "bytes": 340}}
    assert comm["classes"]["bid"]["recv"] == {"messages": 2, "bytes": 140}


def test_commcost_rows_carry_the_orders_per_tick_apart():
    scenario = scenario_from_dict(crossing_scenario(2))
    comm = comm_summary(counted(), "reduced", len(scenario.robot_ids), 0.5)
    summary = {"steps": 10, "sim_time_s": 0.5, "comm": comm, "collisions": 0,
               "all_reached": True, "time_to_goal_s": 0.5, "formation_error_max_m": 0.0,
               "min_clearance_m": {"robot": 1.0}, "qp": {"infeasible": 0},
               "agents": {"stale": 0, "lockstep_timeouts": 0}}
    row = measure_row(scenario, summary, "reduced", 1.0)
    assert row["orders_per_tick"] == 0.5 and row["orders_bytes_per_tick"] == 34.0
    assert row["state_per_tick"] == 2.0  # the orders are not the topology's

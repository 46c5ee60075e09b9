"""``formation commcost``: analytic delivery counts, the crossing generator, and a real
multi-process run of both topologies whose counted traffic matches the analytic counts."""

from __future__ import annotations

import csv
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from experiments.commcost import (
    CSV_COLUMNS,
    analytic_bytes,
    analytic_deliveries,
    constraints_per_robot,
    crossing_scenario,
    fleet_of,
    parse_formations,
    plot,
    plot_series,
    run_commcost,
    wildcard_echo,
    write_outputs,
)
from formation.cli import main
from leader.role import VIEW_RANGE
from scenario.load import scenario_from_dict

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_two_pairs_exchange_eight_deliveries_per_tick_reduced_and_sixteen_all_to_all():
    # reduced: each pair's two robots hear each other (4), the two leaders hear each other's
    # ellipse (2), each member hears its leader's others (2).
    assert analytic_deliveries([2, 2], [1, 1], "reduced") == {"state": 4, "ellipse": 2, "others": 2}
    # all-to-all: 4 robots x 3 others, plus the same ellipses (tie-break, jam rule) and others.
    assert analytic_deliveries([2, 2], [1, 1], "all-to-all") == {"state": 12, "ellipse": 2, "others": 2}


def test_pair_and_rectangle_counts_match_a_hand_count():
    # pair + rectangle: every robot hears every other member of its formation (separation rows
    # need the one member that is not a graph neighbour too): 2 x 1 + 4 x 3 = 14.
    assert analytic_deliveries([2, 4], [1, 5], "reduced") == {"state": 14, "ellipse": 2, "others": 4}
    assert analytic_deliveries([2, 4], [1, 5], "all-to-all") == {"state": 30, "ellipse": 2, "others": 4}
    assert wildcard_echo(6, "all-to-all") == 6
    assert wildcard_echo(6, "reduced") == 0


def test_eight_formation_fleet_is_below_a_quarter_of_all_to_all():
    sizes, edges = [2, 4] * 4, [1, 5] * 4
    red = sum(analytic_deliveries(sizes, edges, "reduced").values())
    a2a = sum(analytic_deliveries(sizes, edges, "all-to-all").values())
    assert (red, a2a) == (56 + 56 + 16, 552 + 56 + 16)
    assert red / a2a < 0.25


def test_constraint_rows_count_formation_and_separation_rows_and_the_rows_for_other_formations():
    # two pairs: each robot has 2 formation rows and 1 separation row, plus 1 ellipse (reduced)
    # or 2 rows for each of 2 foreign robots (eq. 3.5 and separation, all-to-all)
    assert constraints_per_robot([2, 2], [1, 1], "reduced") == 4.0
    assert constraints_per_robot([2, 2], [1, 1], "all-to-all") == 7.0


def test_payload_bytes_of_a_pair_and_a_rectangle_match_the_wire_layout():
    # State 49 B (version 2, with the heading); an ellipse of formation "f0" with its m members'
    # points and headings (version 2) 73 + 3 + 1 + 16 m + 1 + 8 m B: the pair's 126, the
    # rectangle's 174; Others = 1 version + 3 id + 8 stamp + 1 list count + (75 + 2 + 24 m) B per
    # other ellipse + 1 list count + the same for its own ellipse, to each member but the leader
    # (1 and 3).
    # All-to-all exchanges the same ellipses (tie-break, jam rule).
    sc = scenario_from_dict(crossing_scenario(2))
    pair, rect = 75 + 2 + 24 * 2, 75 + 2 + 24 * 4
    others = 1 * (14 + rect + pair) + 3 * (14 + pair + rect)
    assert analytic_bytes(sc, "reduced") == {"state": 14 * 49, "ellipse": 1 + pair + 1 + rect,
                                             "others": others}
    assert analytic_bytes(sc, "all-to-all") == {"state": 30 * 49, "ellipse": 1 + pair + 1 + rect,
                                                "others": others}


def test_others_bytes_count_only_the_formations_each_leader_has_in_view():
    # Two ticks of two formations: beside each other (each has the other in view), then far
    # apart (each hands its members only its own ellipse): the mean of the two ticks.
    sc = scenario_from_dict(crossing_scenario(2))
    a, b = (f.name for f in sc.formations)
    near = [(0.0, a, 0.0, 0.0, 0.0, 0.5, 0.3), (0.0, b, 2.0, 0.0, 0.0, 0.5, 0.3)]
    far = [(0.05, a, 0.0, 0.0, 0.0, 0.5, 0.3), (0.05, b, 2.0 + VIEW_RANGE, 0.0, 0.0, 0.5, 0.3)]
    seen = analytic_bytes(sc, "reduced", near + far)["others"]
    pair, rect = 75 + 2 + 24 * 2, 75 + 2 + 24 * 4  # an ellipse with its members' points, headings
    together = 1 * (14 + rect + pair) + 3 * (14 + pair + rect)
    apart = 1 * (14 + pair) + 3 * (14 + rect)
    assert seen == (together + apart) / 2
    assert analytic_bytes(sc, "reduced", near)["others"] == analytic_bytes(sc, "reduced")["others"]


@given(st.lists(st.integers(2, 6), min_size=2, max_size=10))
def test_reduced_never_exceeds_all_to_all_for_minimally_rigid_formations(sizes):
    edges = [2 * n - 3 for n in sizes]  # Laman count of a minimally rigid graph
    red = analytic_deliveries(sizes, edges, "reduced")
    a2a = analytic_deliveries(sizes, edges, "all-to-all")
    n = sum(sizes)
    assert a2a["state"] == n * (n - 1)
    assert red["others"] == a2a["others"] == n - len(sizes)
    # 2E <= sum n_f (n_f - 1) and L(L-1) <= sum n_f (N - n_f); the two sums add up to N(N-1)
    assert sum(red.values()) <= sum(a2a.values())


@pytest.mark.parametrize("bad, name", [
    (([2, 2], [1], "reduced"), "edges"),
    (([2, 0], [1, 1], "reduced"), "sizes"),
    (([2, 2], [1, 1], "mesh"), "topology"),
])
def test_analytic_counts_reject_bad_input_naming_the_parameter(bad, name):
    with pytest.raises(ValueError, match=name):
        analytic_deliveries(*bad)


@pytest.mark.parametrize("formations", [2, 4, 8])
def test_generated_crossing_is_a_valid_scenario_of_alternating_pairs_and_rectangles(formations):
    sc = scenario_from_dict(crossing_scenario(formations))
    sizes, _edges = fleet_of(sc)
    assert len(sc.formations) == formations
    assert sizes == [2 if k % 2 == 0 else 4 for k in range(formations)]
    assert sc.controller.d_af is not None and sc.controller.d_af > 2 * sc.robot.radius
    # a real crossing: some formations travel east/west and some north/south, through the origin
    travel = []
    for f in sc.formations:
        (sx, sy), (gx, gy) = f.start_centroid, f.goal_centroid
        travel.append((gx - sx, gy - sy))
        assert math.hypot(gx - sx, gy - sy) >= 6.0
    assert any(abs(dx) > abs(dy) for dx, dy in travel)
    assert any(abs(dy) > abs(dx) for dx, dy in travel)


def test_generated_crossings_validate_for_every_supported_fleet_size():
    for formations in range(2, 17):
        scenario_from_dict(crossing_scenario(formations))


def test_formations_list_is_parsed_and_bad_entries_name_the_option():
    assert parse_formations("8, 2,4,2") == [2, 4, 8]
    for bad in ("1", "2,x", "17", ""):
        with pytest.raises(ValueError, match="--formations"):
            parse_formations(bad)


def test_commcost_with_one_formation_exits_2_naming_the_option(tmp_path, capsys):
    assert main(["commcost", "--formations", "1", "--out", str(tmp_path)]) == 2
    assert "--formations" in capsys.readouterr().err


@pytest.mark.integration
def test_real_run_of_both_topologies_counts_exactly_the_analytic_deliveries(tmp_path):
    # A shortened crossing (the formations meet around t = 16 s) keeps the test quick; the
    # counts per tick do not depend on the duration.
    rows = run_commcost([2], tmp_path, duration=12.0)
    write_outputs(rows, tmp_path)
    by = {r["topology"]: r for r in rows}
    assert set(by) == {"reduced", "all-to-all"}
    for topology, r in by.items():
        assert r["steps"] == 240 and r["collisions"] == 0
        assert r["stale_ticks"] == 0 and r["lockstep_timeouts"] == 0
        # lock-step: every delivery belongs to a tick, none before the first or after the last
        assert r["state_per_tick"] == r["analytic_state_per_tick"], topology
        assert r["ellipse_per_tick"] == r["analytic_ellipse_per_tick"], topology
        assert r["others_per_tick"] == r["analytic_others_per_tick"], topology
        assert r["echo_per_tick"] == wildcard_echo(r["robots"], topology)
        assert r["state_bytes_per_tick"] == r["analytic_state_bytes_per_tick"], topology
        assert r["ellipse_bytes_per_tick"] == r["analytic_ellipse_bytes_per_tick"], topology
        assert r["others_bytes_per_tick"] == r["analytic_others_bytes_per_tick"], topology
        assert r["messages_per_robot_per_s"] == pytest.approx(r["analytic_messages_per_robot_per_s"])
        assert r["bytes_per_robot_per_s"] == pytest.approx(r["analytic_bytes_per_robot_per_s"])
        # poses, obstacles and commands: one each per robot per tick, not counted above
        assert r["shared_per_tick"] == pytest.approx(3 * r["robots"], abs=r["robots"] / r["steps"] + 1e-9)
    assert by["reduced"]["messages_per_robot_per_s"] < by["all-to-all"]["messages_per_robot_per_s"]
    assert by["reduced"]["bytes_per_robot_per_s"] < by["all-to-all"]["bytes_per_robot_per_s"]
    with (tmp_path / "commcost.csv").open(encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert [r["topology"] for r in table] == ["reduced", "all-to-all"]
    assert set(CSV_COLUMNS) <= set(table[0])
    md = (tmp_path / "commcost.md").read_text(encoding="utf-8")
    assert "| 2 | 6 |" in md
    assert (tmp_path / "commcost.png").read_bytes()[:8] == PNG_MAGIC
    series = plot_series(rows)  # the figure's measured markers sit on its analytic ones
    for (key, topology, kind), (xs, ys) in series.items():
        if kind == "measured":
            assert (xs, pytest.approx(ys)) == series[(key, topology, "analytic")]
    assert (tmp_path / "scenarios" / "commcost-2.yaml").is_file()
    assert (tmp_path / "runs" / "reduced-2" / "summary.json").is_file()


def _row(formations: int, topology: str, robots: int, measured: float, analytic: float) -> dict:
    return {"formations": formations, "topology": topology, "robots": robots,
            "messages_per_robot_per_s": measured, "analytic_messages_per_robot_per_s": analytic,
            "bytes_per_robot_per_s": 10 * measured, "analytic_bytes_per_robot_per_s": 10 * analytic}


def test_the_figure_draws_the_analytic_value_only_where_it_was_measured_and_the_runs_own(tmp_path):
    rows = [_row(2, "reduced", 6, 40.0, 40.0), _row(2, "all-to-all", 6, 100.0, 100.0),
            _row(5, "reduced", 14, 45.0, 45.5), _row(5, "all-to-all", 14, 260.0, 260.0)]
    series = plot_series(rows)
    assert series[("messages_per_robot_per_s", "reduced", "analytic")] == ([6, 14], [40.0, 45.5])
    assert series[("bytes_per_robot_per_s", "all-to-all", "analytic")] == ([6, 14], [1000.0, 2600.0])
    assert series[("bytes_per_robot_per_s", "reduced", "measured")] == ([6, 14], [400.0, 450.0])
    assert {xs == [6, 14] for xs, _ in series.values()} == {True}  # no robot count between
    plot(rows, tmp_path / "commcost.png")
    assert (tmp_path / "commcost.png").read_bytes()[:8] == PNG_MAGIC

"""Escape from hazards the robots cannot outrun.

The envelope (a forklift up to 1.5 x the robots' top speed, first seen at least 4 m away, room to
step aside) ends with no contact, for a parked and a moving formation, from five bearings; where
escape is physically impossible the robots take the least-risk command, and it is counted. A
formation as fast as the robots (all formations share one robot model) is met by the tie-break
and by the formation's rigid motion (agent.body), whose rows keep its footprint off the other
formations' ellipses: the scenarios
tests/scenarios/formation-*.yaml run in tests/test_simulation.py; here one of them runs in
separate processes, lock-step, exactly as in-process.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from agent.qp import STATUS_FALLBACK
from formation.cli import main
from scenario import parse_scenario
from simulator.inprocess import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[1]
VMAX = 0.22


# ------------------------------------------------------------------------------ envelope

_OPEN_FLOOR = """
name: envelope
dt: 0.05
duration: {duration}
robot: {{max_speed: 0.22, radius: 0.105}}
controller: {{kp: 2.0, gamma: {{formation: 1.0, obstacle: 0.8, formations: 0.5}}, epsilon: 0.04}}
formations:
  - name: F
    leader: f1
    robots:
      f1: {{start: [{x1}, 0.15], goal: [{g1}, 0.15]}}
      f2: {{start: [{x1}, -0.15], goal: [{g1}, -0.15]}}
      f3: {{start: [{x0}, -0.15], goal: [{g0}, -0.15]}}
      f4: {{start: [{x0}, 0.15], goal: [{g0}, 0.15]}}
    edges: [[f1, f2], [f1, f3], [f1, f4], [f2, f3], [f3, f4]]
obstacles:
  - {{name: forklift, center: [{hx}, {hy}], safe_distance: 0.5, velocity: [{hvx}, {hvy}]}}
"""


def _envelope(bearing_deg: float, moving: bool, seen: float = 4.0, duration: float = 45.0):
    return parse_scenario(_envelope_text(bearing_deg, moving, seen, duration))


def _envelope_text(bearing_deg: float, moving: bool, seen: float = 4.0,
                   duration: float = 45.0) -> str:
    """A 0.5 x 0.3 m rectangle at the origin (parked, or driving east at top speed); a forklift
    at 1.5 x top speed, safe distance 0.5 m, first seen ``seen`` m from the formation's
    outline, coming from ``bearing_deg`` straight at the formation."""
    b = math.radians(bearing_deg)
    speed = 1.5 * VMAX
    d = seen + 0.5 + 0.25  # centre to centre: the forklift's Ds and the rectangle's half-length
    hx, hy = d * math.cos(b), d * math.sin(b)
    # aim at where the formation will be when the forklift gets there: |(w t, 0) - h| = s t
    w = VMAX if moving else 0.0
    qa, qb, qc = w * w - speed * speed, -2.0 * w * hx, d * d
    t_hit = (-qb - math.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)
    vx, vy = w * t_hit - hx, -hy
    n = math.hypot(vx, vy)
    goal_dx = 8.0 if moving else 0.0
    text = _OPEN_FLOOR.format(duration=duration, x1=0.25, x0=-0.25, g1=0.25 + goal_dx,
                              g0=-0.25 + goal_dx, hx=round(hx, 4), hy=round(hy, 4),
                              hvx=round(speed * vx / n, 4), hvy=round(speed * vy / n, 4))
    return text


@pytest.mark.parametrize("moving", [False, True], ids=["parked", "moving"])
@pytest.mark.parametrize("bearing", [180.0, 135.0, 90.0, 45.0, 0.0])
def test_inside_the_envelope_a_formation_escapes_a_forklift_half_again_as_fast_with_no_contact(
        bearing, moving):
    s = simulate(_envelope(bearing, moving), SimOptions(record=False)).summary
    assert s["collisions"] == 0
    assert s["min_clearance_m"]["obstacle"] >= 0.0
    assert s["qp"]["fallback"] == 0 and s["qp"]["hard_row_unmet_ticks"] == 0
    assert s["qp"]["escape"] > 0
    assert s["formation_error_max_m"] <= 1.5 * 0.04


# ---------------------------------------------------------------- escape impossible

_CORRIDOR = """
name: no-room
dt: 0.05
duration: 40.0
robot: {max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: {formation: 1.0, obstacle: 0.8, formations: 0.5}, epsilon: 0.04}
formations:
  - name: F
    leader: f1
    robots:
      f1: {start: [0.25, 0.15], goal: [6.25, 0.15]}
      f2: {start: [0.25, -0.15], goal: [6.25, -0.15]}
      f3: {start: [-0.25, -0.15], goal: [5.75, -0.15]}
      f4: {start: [-0.25, 0.15], goal: [5.75, 0.15]}
    edges: [[f1, f2], [f1, f3], [f1, f4], [f2, f3], [f3, f4]]
obstacles:
  - {name: north, segment: [[-15.0, 0.7], [15.0, 0.7]], safe_distance: 0.2}
  - {name: south, segment: [[-15.0, -0.7], [15.0, -0.7]], safe_distance: 0.2}
  - {name: forklift, center: [-4.5, 0.0], safe_distance: 0.5, velocity: [0.33, 0.0]}
"""


def test_where_escape_is_impossible_the_robots_take_the_least_risk_command_and_count_it(tmp_path):
    """A corridor 1.0 m clear between its walls (1.4 m apart, Ds 0.2 m) holds a 0.5 x 0.3 m
    rectangle driving along it, but leaves no room beside a forklift with a 0.5 m safe distance
    on its centre line (1.0 m < 0.3 m + 2 x 0.5 m), and the forklift, 1.5 x the robots' top
    speed, catches it from behind: the formation can neither step aside nor outrun it. The
    robots flee as fast as they can; when the hard rows cannot all hold, the QP returns the
    least-risk command (contact rows relaxed by their smallest common slack, inside the speed
    limits), and every such tick is counted in the summary."""
    path = tmp_path / "no-room.yaml"
    path.write_text(_CORRIDOR, encoding="utf-8")
    assert main(["sim", str(path), "--out", str(tmp_path / "o"), "--quiet", "--no-plots"]) == 0
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["qp"]["fallback"] > 0
    assert s["qp"]["hard_row_unmet"]["fallback"] == s["qp"]["fallback"]
    assert s["qp"]["hard_row_unmet_ticks"] >= s["qp"]["fallback"]
    assert s["qp"]["escape"] > 0  # it tried
    assert s["min_clearance_m"]["obstacle"] < 0.0  # and the forklift, which avoids nothing, won
    # the least-risk command flees: along the corridor, away from the forklift, at top speed
    rows = (tmp_path / "o" / "robots.csv").read_text().splitlines()
    head = rows[0].split(",")
    fallback = [dict(zip(head, r.split(","), strict=True)) for r in rows[1:]]
    fallback = [r for r in fallback if r["status"] == STATUS_FALLBACK]
    assert fallback
    for r in fallback:
        ux, uy = float(r["ux"]), float(r["uy"])
        assert math.hypot(ux, uy) <= VMAX + 1e-6
    assert max(float(r["ux"]) for r in fallback) > 0.9 * VMAX


# --------------------------------------------------------------- separate processes

_LOCKSTEP = """
# A pair at top speed meets a parked pair head-on on one line: they pass, without contact.
name: give-way-lockstep
dt: 0.1
duration: 40.0
robot: {max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: {formation: 1.0, obstacle: 0.8, formations: 0.5}, epsilon: 0.05}
formations:
  - name: carrier
    leader: c1
    robots:
      c1: {start: [2.6, 0.0], goal: [-2.6, 0.0]}
      c2: {start: [3.1, 0.0], goal: [-2.1, 0.0]}
    edges: [[c1, c2]]
  - name: dock
    leader: d1
    robots:
      d1: {start: [-0.25, 0.0], goal: [-0.25, 0.0]}
      d2: {start: [0.25, 0.0], goal: [0.25, 0.0]}
    edges: [[d1, d2]]
"""


@pytest.mark.integration
def test_a_formation_passing_a_parked_one_runs_in_separate_processes_exactly_as_in_process(tmp_path):
    path = tmp_path / "give-way.yaml"
    path.write_text(_LOCKSTEP, encoding="utf-8")
    assert main(["sim", str(path), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet", "--no-plots"]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    ys = [abs(float(line.split(",")[4]))
          for line in (tmp_path / "sim" / "robots.csv").read_text().splitlines()[1:]]
    assert max(ys) > 0.2  # they met on one line: one went round the other
    assert run["mode"] == "multiprocess" and run["all_reached"] and run["collisions"] == 0
    assert run["formation_error_max_m"] <= 1.5 * 0.05
    assert (tmp_path / "run" / "robots.csv").read_text() == (tmp_path / "sim" / "robots.csv").read_text()


@pytest.mark.integration
def test_agents_count_their_escape_ticks_as_the_in_process_simulation_does(tmp_path):
    """A forklift from behind a parked rectangle, in separate processes (lock-step): the agents
    count the ticks on which the escape set their nominal, and summary.json sums them to the
    in-process count."""
    path = tmp_path / "escape.yaml"
    path.write_text(_envelope_text(180.0, False, duration=12.0), encoding="utf-8")
    assert main(["sim", str(path), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet", "--no-plots"]) == 0
    sim = json.loads((tmp_path / "sim" / "summary.json").read_text())
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert sim["qp"]["escape"] > 0
    assert run["qp"]["escape"] == sim["qp"]["escape"]

"""Double-integrator robots (:mod:`agent.double_integrator`): each barrier's
one-step property under the exact sampled double integrator, the limit rows, braking, the
model's scenarios in process (0 collisions, <= 1.5 epsilon, every goal), a lock-step run equal
to ``sim``, the ``cmd`` payload's version 2, and the scenario's and agent config's checks."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest
import zenoh
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize

from agent import double_integrator as di
from agent.accel_limit import STATUS_ACCEL
from agent.barriers import Neighbour, Obstacle, Partner, speed_rows
from agent.barriers import obstacle_row as obstacle_row_si
from agent.config import build_agent_configs, load_config, save_config
from agent.control import Controller, ControlParams, StepInput
from agent.qp import STATUS_OK, solve_exact
from formation.cli import main
from geometry.ellipse import Ellipse, ellipse_terms
from geometry.shapes import box, segment, shape_distance
from scenario import ScenarioError, load_scenario, parse_scenario
from simulator.inprocess import SimOptions, simulate
from tests.same_files import assert_same
from tests.scenario_runs import summary_of
from wire.payloads import CMD_ACCEL_VERSION, Cmd, DecodeError, decode_cmd, encode

SCENARIOS = Path(__file__).parent / "scenarios"
THESIS = Path(__file__).parents[1] / "scenarios"
DI_SCENARIOS = ["di-thesis-move", "di-circle", "di-shelf", "di-crossing", "di-forklift",
                "di-three-cross", "di-pushed-to-shelves", "di-shelf-rows-deadlock"]
TOL = 1e-9

coord = st.floats(-3.0, 3.0)
gap = st.one_of(st.floats(0.0, 1e-3), st.floats(0.0, 0.5))  # h: most cases close to the boundary
speed = st.floats(0.0, 0.5)
angle = st.floats(-math.pi, math.pi)
accel = st.floats(0.1, 3.0)
period = st.floats(0.01, 0.2)
gamma = st.floats(0.1, 20.0)


def _polar(r: float, a: float) -> tuple[float, float]:
    return (r * math.cos(a), r * math.sin(a))


def _solve(a_nom: tuple[float, float], v: tuple[float, float], vmax: float, amax: float,
           dt: float, rows: list) -> tuple[float, float] | None:
    """The QP of one tick over these barrier rows with the limit rows."""
    limits = di.accel_limit_rows(v, v, a_nom, vmax, amax, dt)
    return solve_exact(a_nom[0], a_nom[1], limits + rows)


def _moved(p, v, a, t):
    return (p[0] + v[0] * t + 0.5 * a[0] * t * t, p[1] + v[1] * t + 0.5 * a[1] * t * t)


# --- the one-step property: h >= 0 over the whole period, no sampling margin ----------------


@settings(max_examples=600, deadline=None)
@given(gap, angle, st.tuples(speed, angle), st.tuples(speed, angle), st.floats(0.05, 1.0), accel,
       period, gamma, st.tuples(speed, angle))
def test_a_circle_barrier_holds_over_the_period_where_the_qp_is_feasible(
        h0, oa, robot_v, obstacle_v, ds, amax, dt, g, nominal):
    """Module docstring, "Sampling": with h >= 0, psi1 >= 0 and the row met, the circle's
    h = |p - o| - Ds stays >= 0 at every instant of the period (the obstacle moving at w)."""
    (vs, va), (ws, wa), (an, aa) = robot_v, obstacle_v, nominal
    p, v, w = (0.0, 0.0), _polar(vs, va), _polar(ws, wa)
    ox, oy = _polar(ds + h0, oa)
    vmax = 0.5
    o = Obstacle(ox, oy, w[0], w[1], ds)
    h, row = di.obstacle_hocbf(p, v, o, g, amax, vmax, dt)
    hd = di.circle_terms(p, v, (ox, oy), w, ds)[1]
    k = di.gain(g, amax, vmax + ws, dt)
    assume(h >= 0.0 and hd + k * h >= 0.0)
    a = _solve(_polar(an * amax, aa), v, vmax, amax, dt, [row])
    assume(a is not None)
    assert a is not None
    for t in (0.25 * dt, 0.5 * dt, 0.75 * dt, dt):
        q = _moved(p, v, a, t)
        assert math.hypot(q[0] - ox - w[0] * t, q[1] - oy - w[1] * t) - ds >= -TOL


@settings(max_examples=600, deadline=None)
@given(gap, angle, st.tuples(st.floats(0.0, 1.5), st.floats(0.0, 1.0)), st.floats(-1.0, 1.0),
       st.booleans(), st.tuples(speed, angle), accel, period, gamma, st.tuples(speed, angle))
def test_a_wall_or_shelf_barrier_holds_over_the_period_where_the_qp_is_feasible(
        h0, yaw, half, shift, is_box, robot_v, amax, dt, g, nominal):
    """The same for a box whose face, or a segment whose line, lies h0 + Ds from the robot
    (the segment shifted along itself, so its end may be the nearest point)."""
    (vs, va), (an, aa), (hx, hy) = robot_v, nominal, half
    p, v = (0.0, 0.0), _polar(vs, va)
    vmax, ds = 0.5, 0.15
    c, s = math.cos(yaw), math.sin(yaw)
    if is_box:
        r = ds + h0 + hx
        sh = box("s", (r * c, r * s), (2.0 * hx, 2.0 * hy + 0.01), yaw, ds)
    else:
        r = ds + h0
        a = (r * c - s * (shift - hx), r * s + c * (shift - hx))
        b = (r * c - s * (shift + hx + 0.01), r * s + c * (shift + hx + 0.01))
        sh = segment("s", a, b, ds)
    h, row = di.shape_hocbf(p, v, sh, g, amax, vmax, dt)
    k = di.gain(g, amax, vmax, dt)
    assume(h >= 0.0 and -row[0] * v[0] - row[1] * v[1] + k * h >= 0.0)  # psi1 = g . v + k h
    a = _solve(_polar(an * amax, aa), v, vmax, amax, dt, [row])
    assume(a is not None)
    assert a is not None
    for t in (0.25 * dt, 0.5 * dt, 0.75 * dt, dt):
        q = _moved(p, v, a, t)
        assert shape_distance(q[0], q[1], sh)[0] - sh.ds >= -TOL


@settings(max_examples=600, deadline=None)
@given(gap, angle, speed, angle, speed, angle, accel, period, gamma)
def test_two_robots_acting_at_once_keep_their_bodies_apart_over_the_period(
        h0, qa, vs, va, us, ua, amax, dt, g):
    """Each robot solves its own QP with its half of the pair's row (the reciprocal split),
    both driving at each other at full acceleration: the bodies stay dsep apart over the
    period."""
    vmax, dsep = 0.5, 0.21
    qx, qy = _polar(dsep + h0, qa)
    cp = ControlParams(max_speed=vmax, period=dt, double_integrator=True, max_accel=amax,
                       gamma_formation=g)
    p, q = (0.0, 0.0), (qx, qy)
    vi, vj = _polar(vs, va), _polar(us, ua)
    hi, ri = di.separation_hocbf(p, vi, Partner(q[0], q[1], vj[0], vj[1]), dsep, g, amax, vmax, dt)
    _, rj = di.separation_hocbf(q, vj, Partner(p[0], p[1], vi[0], vi[1]), dsep, g, amax, vmax, dt)
    hd = di.circle_terms(p, vi, q, vj, dsep)[1]
    k = di.gain(cp.gamma_formation, 2.0 * amax, 2.0 * vmax, dt)
    assume(hi >= 0.0 and hd + k * hi >= 0.0)
    ai = _solve(_polar(amax, qa), vi, vmax, amax, dt, [ri])
    aj = _solve(_polar(amax, qa + math.pi), vj, vmax, amax, dt, [rj])
    assume(ai is not None and aj is not None)
    assert ai is not None and aj is not None
    for t in (0.25 * dt, 0.5 * dt, 0.75 * dt, dt):
        a, b = _moved(p, vi, ai, t), _moved(q, vj, aj, t)
        assert math.hypot(a[0] - b[0], a[1] - b[1]) - dsep >= -TOL


@settings(max_examples=400, deadline=None)
@given(gap, angle, st.tuples(speed, angle), st.tuples(speed, angle), accel, period, gamma)
def test_one_circle_row_is_feasible_wherever_the_robot_is_outside_its_first_stage(
        h0, oa, robot_v, obstacle_v, amax, dt, g):
    """Module docstring, "Outside the first stage": there the second pole is capped, so a
    circle's row asks at most (brake_share + restore_share) max_accel by the poles alone (the
    cap of :func:`agent.double_integrator.most_asked` never binds) and is feasible."""
    (vs, va), (ws, wa) = robot_v, obstacle_v
    vmax = 0.5
    v, w = _polar(min(vs, vmax), va), _polar(min(ws, vmax), wa)
    ox, oy = _polar(0.3 + h0, oa)
    h, row = di.obstacle_hocbf((0.0, 0.0), v, Obstacle(ox, oy, w[0], w[1], 0.3), g, amax, vmax, dt)
    hd = di.circle_terms((0.0, 0.0), v, (ox, oy), w, 0.3)[1]
    k = di.gain(g, amax, vmax + math.hypot(*w), dt)
    b = di.hocbf_bound(h, hd, k, dt, di.DI_TUNING.restore_share * amax)
    assert h >= -TOL and b >= -di.most_asked(amax) - TOL and row[2] == pytest.approx(b)
    assert _solve((0.0, 0.0), v, vmax, amax, dt, [row]) is not None


def test_a_turning_ellipse_far_away_asks_no_more_braking_than_one_row_may():
    """Module docstring, "Outside the first stage": the level sets of a turning ellipse's h
    sweep at its turn rate times the distance; a robot at rest 4 m away keeps a feasible row."""
    amax, dt, vmax = 0.5, 0.05, 0.22
    e = Ellipse(-1.7, -0.41, 1.3, 0.62, 0.35, 0.002, 0.028, 0.53)
    h, row = di.ellipse_hocbf((0.54, -4.16), (0.0, 0.0), e, 0.5, amax, vmax, dt)
    assert h > 0.0 and row[2] == pytest.approx(-di.most_asked(amax))
    assert _solve((0.0, 0.0), (0.0, 0.0), vmax, amax, dt, [row]) is not None


@settings(max_examples=400, deadline=None)
@given(gap, st.floats(-0.5, 0.5), st.tuples(speed, angle), accel, period, gamma,
       st.tuples(speed, angle))
def test_a_wall_face_row_met_keeps_the_first_stage_at_the_next_sample(
        h0, shift, robot_v, amax, dt, g, nominal):
    """Module docstring, "Sampling": for a barrier linear in the position (a long wall's face)
    a robot inside {h >= 0, psi1 >= 0} that meets the row is inside it again a period later."""
    (vs, va), (an, aa) = robot_v, nominal
    vmax, ds = 0.5, 0.15
    v = _polar(vs, va)
    wall = segment("w", (ds + h0, shift - 5.0), (ds + h0, shift + 5.0), ds)
    k = di.gain(g, amax, vmax, dt)
    h, row = di.shape_hocbf((0.0, 0.0), v, wall, g, amax, vmax, dt)
    assume(h >= 0.0 and -v[0] + k * h >= 0.0)  # g = (-1, 0): psi1 = -vx + k h
    a = _solve(_polar(an * amax, aa), v, vmax, amax, dt, [row])
    assume(a is not None)
    assert a is not None
    (x, _), vx = _moved((0.0, 0.0), v, a, dt), v[0] + a[0] * dt
    h1 = ds + h0 - x - ds
    assert h1 >= -TOL and -vx + k * h1 >= -TOL


def test_a_formation_at_rest_accelerates_as_one_through_its_band_and_separation_rows():
    """Module docstring, "Poles": two members at rest a band's middle apart (thesis 5.1.2: gamma
    0.5, epsilon 0.035, edge 0.25 m) may each accelerate along their edge, towards and away from
    the other, at a third of max_accel under the band and separation rows alone."""
    amax, dt = 0.5, 0.05
    cp = ControlParams(gamma_formation=0.5, epsilon=0.035, max_speed=0.22, period=dt,
                       double_integrator=True, max_accel=amax, radius=0.105)
    n = Neighbour(0.25, 0.0, 0.0, 0.0, 0.25)
    _, _, row_g, row_l = di.band_hocbf((0.0, 0.0), (0.0, 0.0), n, cp.epsilon,
                                      min(cp.gamma_formation, 0.5 / dt), dt, amax)
    _, sep = di.separation_hocbf((0.0, 0.0), (0.0, 0.0), Partner(0.25, 0.0, 0.0, 0.0),
                                 cp.separation, cp.gamma_formation, amax, cp.max_speed, dt)
    for ax in (amax / 3.0, -amax / 3.0):  # towards the other member and away from it
        assert all(nx * ax <= b for nx, _, b in (row_g, row_l, sep))


# --- limits, nominal, braking -----------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(speed, angle, speed, angle, accel, period, coord, coord)
def test_the_certified_acceleration_keeps_both_limits(vs, va, us, ua, amax, dt, gx, gy):
    vmax = 0.5
    face = vmax * math.cos(math.pi / 12)
    v = _polar(min(vs, face), va)  # inside every speed polygon, whatever its heading
    cp = ControlParams(max_speed=vmax, period=dt, double_integrator=True, max_accel=amax)
    res = Controller(cp).step(StepInput((0.0, 0.0, 0.0), (gx, gy),
                                        obstacles=[Obstacle(1.0, 0.0, 0.0, 0.0, 0.3)], last_u=v))
    assert math.hypot(res.ax, res.ay) <= amax + 1e-9
    assert math.hypot(v[0] + res.ax * dt, v[1] + res.ay * dt) <= vmax + 1e-9
    assert (res.ux, res.uy) == pytest.approx((v[0] + res.ax * dt, v[1] + res.ay * dt), abs=1e-12)


def test_the_nominal_acceleration_tracks_the_nominal_velocity_and_is_clamped():
    assert di.nominal_accel((0.1, 0.0), (0.0, 0.0), 2.0, 10.0) == pytest.approx((0.4, 0.0))
    assert math.hypot(*di.nominal_accel((0.2, 0.2), (-0.2, 0.0), 2.0, 0.5)) == pytest.approx(0.5)


@pytest.mark.parametrize("amax", [0.1, 0.3, 1.0])
def test_a_robot_at_full_speed_brakes_before_a_wall_in_its_way(amax):
    """Driving at 0.22 m/s at a wall beyond which its goal lies, the robot stops short of the
    wall's safe distance whatever its acceleration limit: the barrier asked for braking in
    time (module docstring, "Braking distance")."""
    dt, vmax = 0.05, 0.22
    cp = ControlParams(max_speed=vmax, period=dt, double_integrator=True, max_accel=amax)
    wall = segment("w", (1.0, -2.0), (1.0, 2.0), 0.15)
    x, y, v = 0.0, 0.0, (vmax, 0.0)
    closest = math.inf
    for _ in range(600):
        res = Controller(cp).step(StepInput((x, y, 0.0), (3.0, 0.0), shapes=[wall], last_u=v))
        assert res.status == STATUS_OK
        x, y, vx, vy = di.integrate(x, y, v[0], v[1], res.ax, res.ay, dt, vmax)
        v = (vx, vy)
        closest = min(closest, shape_distance(x, y, wall)[0] - wall.ds)
    assert closest >= -TOL
    assert math.hypot(*v) < 1e-3 and 1.0 - wall.ds - x < 0.01  # stopped at the safe distance


def test_brake_stops_a_robot_at_its_acceleration_limit():
    v, steps = (0.2, -0.1), 0
    while math.hypot(*v) > 0.0 and steps < 100:
        a = di.brake(v[0], v[1], 0.5, 0.05)
        assert math.hypot(*a) <= 0.5 + 1e-12
        v = di.integrate(0.0, 0.0, v[0], v[1], a[0], a[1], 0.05, 1.0)[2:]
        steps += 1
    assert steps == math.ceil(math.hypot(0.2, 0.1) / (0.5 * 0.05))


def test_a_speed_polygon_face_the_velocity_is_beyond_is_not_pushed_further():
    v = (0.25, 0.0)  # beyond the face of a 0.22 m/s polygon turned away from it
    rows = di.accel_limit_rows(v, (0.0, 1.0), (0.0, 1.0), 0.22, 1.0, 0.05)
    assert all(nx * 0.0 + ny * 0.0 <= b for nx, ny, b in rows)  # a = 0 meets every row
    assert len(rows) == 2 * len(speed_rows(1.0, 0.0))


@settings(max_examples=300, deadline=None)
@given(coord, coord, st.tuples(speed, angle), st.tuples(speed, angle), st.floats(0.2, 1.5),
       st.floats(0.1, 1.0), angle, st.floats(0.1, 5.0), accel, period)
def test_a_slot_velocity_the_double_integrators_twist_allows_asks_no_braking_of_its_member(
        px, py, v, ve, a, b_ratio, alpha, gamma, amax, dt):
    # the twist's ellipse row (agent.body, linear alpha = twist_gamma h) met by the slot velocity
    # v: then a = 0 meets the member's own relative-degree-2 row for that ellipse (not turning)
    vmax = 0.22
    cp = ControlParams(gamma_formations=gamma, max_accel=amax, double_integrator=True, period=dt)
    vel, vel_e = _polar(min(v[0], vmax), v[1]), _polar(min(ve[0], vmax), ve[1])
    e = Ellipse(0.0, 0.0, alpha, a, a * b_ratio, *vel_e)
    h, gx, gy, _ = ellipse_terms(px, py, e.cx, e.cy, e.alpha, e.a, e.b)
    assume(h > 0.0)
    assume(gx * (vel[0] - vel_e[0]) + gy * (vel[1] - vel_e[1]) >= -di.twist_gamma(cp) * h)
    _, (_, _, bound) = di.ellipse_hocbf((px, py), vel, e, gamma, amax, vmax, dt)
    assert bound >= -TOL


# --- the model's scenarios ---------------------------------------------------------------------


@pytest.mark.parametrize("name", DI_SCENARIOS)
def test_double_integrator_scenarios_meet_the_bar(name):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    assert s.robot.is_double_integrator and s.robot.max_accel is not None
    summary = summary_of(SCENARIOS / f"{name}.yaml")
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    assert summary["all_reached"]
    assert summary["qp"]["hard_row_unmet_ticks"] == 0, summary["qp"]["hard_row_unmet"]


@pytest.mark.parametrize("stem", ["5.1.1", "5.1.2", "5.2.1", "5.2.2"])
def test_double_integrators_with_ample_acceleration_keep_the_single_integrators_pace(stem):
    """The thesis's scenarios with double integrators of max_accel 0.5 m/s^2 in place of its
    single integrators: every goal within 1.5 times the single integrators' time, safely."""
    path = THESIS / f"thesis-{stem}.yaml"
    single = summary_of(path)
    s = parse_scenario(path.read_text().replace(
        "model: single_integrator,", "model: double_integrator, max_accel: 0.5,"))
    assert s.robot.is_double_integrator and single["all_reached"]
    summary = simulate(s, SimOptions(record=False)).summary
    assert summary["all_reached"]
    assert summary["time_to_goal_s"] <= 1.5 * single["time_to_goal_s"]
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    assert summary["qp"]["hard_row_unmet_ticks"] == 0, summary["qp"]["hard_row_unmet"]


def test_a_lockstep_run_of_double_integrators_equals_the_simulation(tmp_path):
    path = SCENARIOS / "di-crossing.yaml"
    assert main(["sim", str(path), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                 "--insecure"]) == 0
    assert_same(tmp_path / "sim" / "robots.csv", tmp_path / "run" / "robots.csv")
    sim = (tmp_path / "sim" / "robots.csv").read_bytes()
    assert sim.splitlines()[0].endswith(b",h_formations,ax,ay")
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["all_reached"]


def test_robots_csv_gains_no_columns_for_the_other_models(tmp_path):
    path = SCENARIOS / "two-small.yaml"
    assert main(["sim", str(path), "--out", str(tmp_path), "--quiet", "--no-plots"]) == 0
    head = (tmp_path / "robots.csv").read_bytes().splitlines()[0]
    assert head.endswith(b",h_formations")


# --- the wire ----------------------------------------------------------------------------------


def test_cmd_version_1_is_unchanged_and_version_2_carries_the_acceleration():
    plain = Cmd(0.1, 0.2, 0.3, 0.4, 5.0)
    raw = encode(plain)
    assert raw[0] == 1 and len(raw) == 41 and decode_cmd(raw) == plain
    with_accel = Cmd(0.1, 0.0, 0.08, 0.06, 5.0, 0.4, -0.3)
    raw2 = encode(with_accel)
    assert raw2[0] == CMD_ACCEL_VERSION and len(raw2) == 57
    assert decode_cmd(raw2) == with_accel
    assert z_deserialize(tuple[UInt8, float, float, float, float, float, float, float],
                         zenoh.ZBytes(raw2)) == (2, 0.1, 0.0, 0.08, 0.06, 0.4, -0.3, 5.0)
    with pytest.raises(DecodeError):
        decode_cmd(raw2[:-8])
    with pytest.raises(DecodeError, match="unsupported version 3"):
        decode_cmd(bytes([3]) + raw2[1:])
    with pytest.raises(ValueError, match="ay"):
        Cmd(0.1, 0.0, 0.0, 0.0, 5.0, 0.4)
    with pytest.raises(ValueError, match="ax"):
        Cmd(0.1, 0.0, 0.0, 0.0, 5.0, math.nan, 0.0)


# --- the scenario and the agent's config ---------------------------------------------------------


def _di_text(robot: str) -> str:
    text = (SCENARIOS / "di-thesis-move.yaml").read_text()
    return text.replace("robot: {model: double_integrator, max_speed: 0.22, max_accel: 0.5, "
                        "radius: 0.105}", f"robot: {robot}")


def test_a_double_integrator_needs_max_accel_in_range():
    with pytest.raises(ScenarioError, match=r"robot\.max_accel: required"):
        parse_scenario(_di_text("{model: double_integrator}"))
    with pytest.raises(ScenarioError, match=r"robot\.max_accel: must be positive"):
        parse_scenario(_di_text("{model: double_integrator, max_accel: 0}"))
    with pytest.raises(ScenarioError, match="robot.model: 'triple_integrator' is not one of"):
        parse_scenario(_di_text("{model: triple_integrator, max_accel: 1}"))
    with pytest.raises(ValueError, match="max_accel"):
        ControlParams(max_accel=-1.0)


def test_double_integrators_are_refused_in_a_lab_world(tmp_path, capsys):
    with pytest.raises(ScenarioError, match="double_integrator runs in the ideal world only"):
        parse_scenario(_di_text("{model: double_integrator, max_accel: 0.5}")
                       + "world: {profile: turtlebot3-lab}\n")
    path = str(SCENARIOS / "di-thesis-move.yaml")
    assert main(["sim", path, "--out", str(tmp_path / "a"), "--quiet", "--world",
                 "turtlebot3-lab"]) == 2
    assert main(["sim", path, "--out", str(tmp_path / "b"), "--quiet", "--engine", "mujoco"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "ideal world only" in err[0] and "kinematic world only" in err[1]
    s = load_scenario(path)
    lab = dataclasses.replace(s, world=dataclasses.replace(s.world, profile="turtlebot3-lab"))
    with pytest.raises(ValueError, match="ideal kinematic world only"):  # the last guard
        simulate(lab, SimOptions(record=False))


def test_the_agent_config_carries_the_model_and_other_configs_stay_as_they_were(tmp_path):
    s = load_scenario(SCENARIOS / "di-thesis-move.yaml")
    cfg = build_agent_configs(s)["a1"]
    assert cfg.control.double_integrator and cfg.control.max_accel == 0.5
    save_config(cfg, tmp_path / "a1")
    assert load_config(tmp_path / "a1") == cfg
    single = dataclasses.replace(s, robot=dataclasses.replace(s.robot, model="single_integrator",
                                                              max_accel=None))
    save_config(build_agent_configs(single)["a1"], tmp_path / "s1")
    text = (tmp_path / "s1").read_text()
    assert "max_accel" not in text and "double_integrator" not in text


# --- a unicycle's acceleration limit (agent.accel_limit) ----------------------------------------

UNI = ControlParams(unicycle=True, max_accel=0.5)


@settings(max_examples=300, deadline=None)
@given(coord, coord, angle, coord, coord, st.floats(0.05, 2.0))
def test_a_unicycle_with_max_accel_changes_its_command_by_at_most_max_accel_dt(
        hx, hy, theta, gx, gy, amax):
    """The last command one the robot could take (certified towards another goal at the same
    heading); whatever the new goal, the command moves by at most a_max dt."""
    p = dataclasses.replace(UNI, max_accel=amax)
    before = Controller(UNI).step(StepInput((0.0, 0.0, theta), (hx, hy)))
    last = (before.ux, before.uy)
    res = Controller(p).step(StepInput((0.0, 0.0, theta), (gx, gy), last_u=last))
    assert res.status == STATUS_OK
    assert math.hypot(res.ux - last[0], res.uy - last[1]) <= amax * p.period + 1e-9


def test_the_barrier_rows_win_over_a_unicycles_acceleration_rows():
    """At full speed just short of an obstacle's safe distance, slowing by a_max dt is not
    enough: the obstacle row holds and the tick is marked (and counted) ``accel``."""
    p = dataclasses.replace(UNI, max_accel=0.1)
    grow = p.offset + p.sampling_margin
    o = Obstacle(0.05 + 0.3 + grow + 0.002, 0.0, 0.0, 0.0, 0.3)  # 2 mm from the grown Ds
    res = Controller(p).step(StepInput((0.0, 0.0, 0.0), (3.0, 0.0), obstacles=[o], last_u=(0.22, 0.0)))
    assert res.status == STATUS_ACCEL
    assert res.ux < 0.22 - 0.1 * p.period  # slowed by more than the acceleration rows allow
    _, row = obstacle_row_si(res.px, res.py, o._replace(ds=o.ds + grow), p.gamma_obstacle)
    assert row[0] * res.ux + row[1] * res.uy <= row[2] + 1e-9
    without = Controller(dataclasses.replace(p, max_accel=None)).step(
        StepInput((0.0, 0.0, 0.0), (3.0, 0.0), obstacles=[o], last_u=(0.22, 0.0)))
    assert (without.ux, without.uy) == pytest.approx((res.ux, res.uy))  # the same command


def test_a_unicycle_run_with_max_accel_counts_its_yielded_ticks_and_others_do_not():
    s = load_scenario(SCENARIOS / "unicycle-crossing.yaml")
    limited = dataclasses.replace(s, robot=dataclasses.replace(s.robot, max_accel=0.5))
    summary = simulate(limited, SimOptions(record=False)).summary
    assert summary["qp"]["accel_yielded"] == 0
    assert summary["all_reached"] and summary["collisions"] == 0
    assert "accel_yielded" not in simulate(s, SimOptions(record=False)).summary["qp"]
    with pytest.raises(ScenarioError, match=r"robot\.max_accel: only for"):
        parse_scenario(_di_text("{model: single_integrator, max_accel: 1}"))

"""``formation montecarlo``: random warehouse scenarios, simulated in-process.

Each run draws a layout from its own seed (so a failure can be replayed alone): two shelf rows
with a cross aisle, 2 to 4 formations of 2 to 4 robots (pairs, triangles, rectangles) crossing
the floor along the main aisle or through the cross aisle, optionally a forklift driving along an
outer aisle, and a robot model (single integrator or unicycle). Layouts the validator refuses are
redrawn from the next sub-seed. ``--model`` gives every drawn layout one robot model in place of
the draw's (the layout and the rest of the draw unchanged): a double integrator gets
``max_accel`` = DI_MAX_ACCEL. ``montecarlo.json`` lists the totals and, for every failed run,
its seed and its scenario file (written next to it) so it can be replayed with ``formation sim``.

That is the ``circles`` draw (the default; its shelves are round). The ``warehouse`` draw
(:mod:`experiments.warehouse_draw`) has shelf rows as boxes, walls, pillars, parked and moving
forklifts, and formations of 2 to 6 robots carrying loads under ``controller.method: rigid``.
The ``lifelong`` draw (:mod:`experiments.lifelong_draw`) has halls with docks, racks, a fleet
and a seeded stream of servable orders.
"""

from __future__ import annotations

import dataclasses
import math
import random
from functools import partial
from typing import NamedTuple

from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from scenario import ScenarioError
from scenario.bounds import parse as parse_bounds
from scenario.load import scenario_from_dict
from scenario.world import IDEAL
from simulator.inprocess import SimOptions, simulate

from .blind import draw_patches, spread
from .cluster import run_sweep
from .lifelong_draw import lifelong_problem, lifelong_scenario
from .warehouse_draw import warehouse_problem, warehouse_scenario

# Formation shapes sized for loads robots of 0.21 m diameter carry together (a pair under a
# 0.6 m beam, a triangle under a round table, four under a 0.8 x 0.6 m pallet): offsets from the
# centre [m], edges (rigid graphs), and the leader's index (adjacent to every member).
SHAPES = {
    "pair": ([(0.0, 0.3), (0.0, -0.3)], [(0, 1)], 0),
    "triangle": ([(0.35, 0.0), (-0.175, 0.303), (-0.175, -0.303)], [(0, 1), (1, 2), (0, 2)], 0),
    "rectangle": ([(0.35, 0.2), (0.35, -0.2), (-0.35, -0.2), (-0.35, 0.2)],
                  [(0, 1), (0, 2), (0, 3), (1, 2), (2, 3)], 0),
}
DT = 0.05  # [s] every run's control period
SHELF_Y = 1.8  # [m] shelf rows at +/- this
SHELF_XS = (-4.9, -4.2, -3.5, -2.8, -2.1, 2.1, 2.8, 3.5, 4.2, 4.9)  # cross aisle at |x| < 1.75
MODELS = ("single_integrator", "unicycle", "double_integrator")  # --model's choices
# [m/s^2] a double integrator's acceleration limit under --model double_integrator: that of the
# di-*.yaml test scenarios and docs/scenarios.md's example, a fifth of what a burger's wheels
# give (scenario.world's turtlebot3-lab max_wheel_accel, 2.5), so the braking distance counts.
DI_MAX_ACCEL = 0.5


def random_scenario(seed: int) -> dict:
    """One random warehouse scenario as a scenario-file mapping."""
    rng = random.Random(seed)
    model = rng.choice(["single_integrator", "unicycle"])
    n_form = rng.randint(2, 4)
    # Lanes: main aisle east/west at two heights, cross aisle north/south at two offsets.
    lanes = [("E", -0.45), ("W", 0.45), ("N", -0.45), ("S", 0.45)]
    rng.shuffle(lanes)
    formations = []
    for k in range(n_form):
        direction, lane = lanes[k]
        kind = rng.choice(list(SHAPES))
        offsets, edges, leader = SHAPES[kind]
        heading = {"E": 0.0, "W": math.pi, "N": math.pi / 2, "S": -math.pi / 2}[direction]
        # North/south formations start and end beyond the forklift's aisle, so they cross it
        # rather than park in it (a forklift does not avoid anything).
        start_d = rng.uniform(3.2, 4.2) if direction in "EW" else rng.uniform(3.6, 4.0)
        end_d = rng.uniform(3.2, 4.2) if direction in "EW" else rng.uniform(3.6, 4.0)
        c, s = math.cos(heading), math.sin(heading)
        lat = lane + rng.uniform(-0.1, 0.1)
        sx, sy = -start_d * c - lat * s, -start_d * s + lat * c
        gx, gy = end_d * c - lat * s, end_d * s + lat * c
        name = "abcd"[k]
        robots = {}
        for j, (ox, oy) in enumerate(offsets):
            wx, wy = c * ox - s * oy, s * ox + c * oy
            robots[f"{name}{j + 1}"] = {
                "start": [round(sx + wx, 4), round(sy + wy, 4)],
                "goal": [round(gx + wx, 4), round(gy + wy, 4)],
            }
        formations.append({
            "name": name,
            "leader": f"{name}{leader + 1}",
            "robots": robots,
            "edges": [[f"{name}{i + 1}", f"{name}{j + 1}"] for i, j in edges],
        })
    obstacles = [
        {"name": f"shelf-{'n' if y > 0 else 's'}{i}", "center": [x, y], "safe_distance": 0.35}
        for y in (SHELF_Y, -SHELF_Y) for i, x in enumerate(SHELF_XS)
    ]
    if rng.random() < 0.7:
        y = rng.choice([2.7, -2.7])
        vx = rng.choice([0.1, 0.15, -0.1, -0.15])
        obstacles.append({"name": "forklift", "center": [-5.5 if vx > 0 else 5.5, y],
                          "safe_distance": 0.45, "velocity": [vx, 0.0]})
    return {
        "name": f"montecarlo-{seed}",
        "dt": DT,
        "duration": 150.0,
        "goal_tolerance": 0.05,
        "robot": {"model": model, "max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
                       "epsilon": 0.05},
        "formations": formations,
        "obstacles": obstacles,
    }


CIRCLES, WAREHOUSE, LIFELONG = "circles", "warehouse", "lifelong"
DRAWS = (CIRCLES, WAREHOUSE, LIFELONG)
# each draw's layout (of a sub-seed) and its own checks beyond the scenario's
LAYOUTS = {CIRCLES: random_scenario, WAREHOUSE: warehouse_scenario, LIFELONG: lifelong_scenario}
PROBLEMS = {WAREHOUSE: warehouse_problem, LIFELONG: lifelong_problem}


def draw_layout(seed: int, draw: str = CIRCLES) -> dict:
    """The layout of sub-seed ``seed`` in draw ``draw`` (one of DRAWS)."""
    return LAYOUTS[draw](seed)


def _checked(d: dict, draw: str):
    """The scenario of mapping ``d`` (the scenario checks, and the draw's own)."""
    scenario = scenario_from_dict(d)
    problem = PROBLEMS[draw](scenario) if draw in PROBLEMS else None
    if problem is not None:
        raise ScenarioError(problem)
    return scenario


def with_model(d: dict, model: str | None) -> dict:
    """Layout ``d`` with robot model ``model`` (one of MODELS; None: the draw's own), in place."""
    if model is not None:
        robot = d["robot"]
        robot["model"] = model
        if model == "double_integrator":
            robot["max_accel"] = DI_MAX_ACCEL
    return d


class Blind(NamedTuple):
    """``--localisation`` and ``--blind N``: every run's localisation and its blind patches."""

    localisation: str = "camera"
    patches: int = 0


NO_BLIND = Blind()


def with_blind(d: dict, blind: Blind, seed: int) -> dict:
    """Layout ``d`` with ``blind``'s localisation and patches (none: unchanged), in place."""
    if blind.localisation != "camera":
        d["controller"]["localisation"] = blind.localisation
    if blind.patches:
        d.setdefault("world", {"seed": seed})["camera_blind"] = draw_patches(d, blind.patches,
                                                                             seed)
    return d


def valid_scenario(seed: int, world: str | None = None, bounds: str | None = None,
                   draw: str = CIRCLES, model: str | None = None, blind: Blind = NO_BLIND):
    """The first valid layout from sub-seeds of ``seed``: (mapping, scenario, sub-seed). With
    ``world`` (a profile other than the default), the mapping says so, with the run's seed as
    the world's: its noise is the run's own, and its scenario file replays it exactly. With
    ``bounds`` (``--bounds SPEC``, :mod:`scenario.bounds`), its ``controller.bounds`` too; with
    ``model`` (``--model``), every robot that model (:func:`with_model`); with ``blind``
    (``--localisation``, ``--blind N``), its localisation and N blind patches
    (:func:`experiments.blind.draw_patches`)."""
    for sub in range(50):
        try:
            d = with_model(draw_layout(seed * 1000 + sub, draw), model)
            if world is not None and world != IDEAL:
                d["world"] = {"profile": world, "seed": seed}
            with_blind(d, blind, seed)
            if bounds is not None:
                d["controller"]["bounds"] = dataclasses.asdict(parse_bounds(bounds, DT))
            return d, _checked(d, draw), seed * 1000 + sub
        except ScenarioError:
            continue
    raise RuntimeError(f"seed {seed}: no valid layout in 50 draws")


def run_one(seed: int, world: str | None = None, bounds: str | None = None,
            draw: str = CIRCLES, model: str | None = None, blind: Blind = NO_BLIND) -> dict:
    d, scenario, sub = valid_scenario(seed, world, bounds, draw, model, blind)
    if scenario.lifelong is not None:
        s, orders = lifelong_summary(scenario)
    else:
        s, orders = simulate(scenario, SimOptions(record=False)).summary, {}
    obstacle_clear = s["min_clearance_m"]["obstacle"]
    return {
        "seed": seed,
        "layout_seed": sub,
        "model": scenario.robot.model,
        "formations": len(scenario.formations),
        "robots": len(scenario.robot_ids) + (
            len(scenario.lifelong.fleet.robots) if scenario.lifelong is not None else 0),
        "all_reached": s["all_reached"],
        "time_to_goal_s": s["time_to_goal_s"],
        "collisions": s["collisions"],  # a lifelong run's counts its loads' contacts too
        **({"orders": orders} if orders else {}),
        "formation_error_max_m": s["formation_error_max_m"],
        "epsilon": scenario.controller.epsilon,
        "min_clearance_obstacle_m": obstacle_clear,
        "infeasible_ticks": s["qp"]["infeasible"],
        "fallback_ticks": s["qp"]["fallback"],
        "relaxed_ticks": s["qp"]["relaxed"],
        "escape_ticks": s["qp"]["escape"],
        **({"localisation": s["localisation"]} if "localisation" in s else {}),
        "scenario": d,
    }


def lifelong_summary(scenario) -> tuple[dict, dict]:
    """A lifelong run's summary, with ``all_reached`` only when every order was delivered and
    none got stuck (a stuck order, its team not moving 0.05 m in 120 s, counts as a deadlock),
    and its orders' totals: posted, delivered, failed, open, stuck, and the ticks of carried
    loads' contacts and of robots inside resting loads (each contact is one of the summary's
    collisions)."""
    from simulator.lifelong import simulate_lifelong

    s = simulate_lifelong(scenario, SimOptions(record=False)).summary
    block = s["orders"]
    orders = {k: block[k] for k in ("posted", "delivered", "failed", "open", "stuck")}
    orders["load_contacts"] = block["checks"]["load_contacts"]
    orders["intrusions"] = block["checks"]["intrusions"]
    orders["service_efficiency_median"] = block["service_efficiency"]["median"] \
        if block["service_efficiency"] else None
    s["all_reached"] = s["all_reached"] and not block["stuck"]
    return s, orders


def orders_totals(results: list[dict]) -> dict:
    """The lifelong draw's order totals over its runs."""
    runs = [r["orders"] for r in results if "orders" in r]
    totals = {k: sum(o[k] for o in runs) for k in ("posted", "delivered", "failed", "open",
                                                  "stuck", "load_contacts", "intrusions")}
    totals["runs_with_stuck_order"] = sum(1 for o in runs if o["stuck"])
    return totals


def _model_totals(runs: list[dict]) -> dict:
    """Totals of one robot model's runs (the band and the least-risk ticks per model)."""
    return {
        "runs": len(runs),
        "reached": sum(r["all_reached"] for r in runs),
        "collisions": sum(r["collisions"] for r in runs),
        "deadlocks": sum(1 for r in runs if not r["all_reached"] and not r["collisions"]),
        "worst_formation_error_over_epsilon": max(
            (r["formation_error_max_m"] / r["epsilon"] for r in runs), default=None),
        "runs_over_1_5_epsilon": sum(
            1 for r in runs if r["formation_error_max_m"] > 1.5 * r["epsilon"]),
        "fallback_ticks": sum(r["fallback_ticks"] for r in runs),
        "relaxed_ticks": sum(r.get("relaxed_ticks", 0) for r in runs),
    }


def run_montecarlo(n: int, seed: int, workers: int = 2, progress=None,
                   world: str | None = None, bounds: str | None = None,
                   draw: str = CIRCLES, model: str | None = None,
                   blind: Blind = NO_BLIND,
                   scheduler: str | None = None) -> tuple[dict, list[dict]]:
    """``n`` runs from ``seed``; ``world``: the world profile of every run (default ideal);
    ``bounds``: every run's controller bounds (``--bounds SPEC``; default none); ``draw``: which
    layouts (one of DRAWS); ``model``: every run's robot model (one of MODELS; default the
    draw's own); ``scheduler``: a Dask scheduler's address to run them on (default: ``workers``
    local processes). The results are the same wherever the runs execute."""
    seeds = [seed * 100000 + k for k in range(n)]
    run = partial(run_one, world=world, bounds=bounds, draw=draw, model=model, blind=blind)
    results = run_sweep(run, seeds, workers, scheduler, progress)
    summary = summarize(results, seed, world, draw, bounds, model)
    if draw == LIFELONG:
        summary["orders"] = orders_totals(results)
    if blind != NO_BLIND:
        summary["localisation"] = localisation_totals(results, blind)
    return summary, results


def localisation_totals(results: list[dict], blind: Blind) -> dict:
    """What the runs' filters did (``fused``): each run's largest error against the truth
    (median, p95, worst), its largest confidence radius, refused poses, blind time."""
    locs = [r["localisation"] for r in results if "localisation" in r]
    return {
        "mode": blind.localisation,
        "blind_patches": blind.patches,
        "max_error_m": spread([x["max_error_m"] for x in locs]),
        "max_sigma_m": max((x["max_sigma_m"] for x in locs), default=None),
        "rejected": sum(x["rejected"] for x in locs),
        "over_limit_ticks": sum(x["over_limit_ticks"] for x in locs),
        "blind_s_max": max((x["blind_s"] for x in locs), default=None),
    }


def summarize(results: list[dict], seed: int, world: str | None = None,
              draw: str = CIRCLES, bounds: str | None = None, model: str | None = None) -> dict:
    """``montecarlo.json`` of the runs ``results`` (:func:`run_one`'s, in seed order)."""
    n = len(results)
    failed = [r for r in results if not r["all_reached"] or r["collisions"]]
    deadlocks = [r for r in results if not r["all_reached"] and not r["collisions"]]
    return {
        "runs": n,
        "seed": seed,
        "world": world or IDEAL,
        "bounds": bounds or "none",
        "draw": draw,
        "model": model or "mix",
        "collisions": sum(r["collisions"] for r in results),
        "runs_with_collision": sum(1 for r in results if r["collisions"]),
        "reached_rate": sum(r["all_reached"] for r in results) / n if n else None,
        "deadlocks": len(deadlocks),
        "worst_formation_error_m": max((r["formation_error_max_m"] for r in results), default=None),
        "worst_formation_error_over_epsilon": max(
            (r["formation_error_max_m"] / r["epsilon"] for r in results), default=None),
        "runs_over_1_5_epsilon": sum(
            1 for r in results if r["formation_error_max_m"] > 1.5 * r["epsilon"]),
        "fallback_ticks": sum(r["fallback_ticks"] for r in results),
        "runs_with_fallback": sum(1 for r in results if r["fallback_ticks"]),
        "escape_ticks": sum(r.get("escape_ticks", 0) for r in results),
        "min_obstacle_clearance_m": min(
            (r["min_clearance_obstacle_m"] for r in results
             if r["min_clearance_obstacle_m"] is not None), default=None),
        "relaxed_ticks": sum(r.get("relaxed_ticks", 0) for r in results),
        "by_model": {m: _model_totals([r for r in results if r["model"] == m])
                     for m in MODELS if m != "double_integrator"
                     or any(r["model"] == m for r in results)},
        "over_band": [{"seed": r["seed"], "model": r["model"], "formation_error_over_epsilon":
                       r["formation_error_max_m"] / r["epsilon"]}
                      for r in results if r["formation_error_max_m"] > 1.5 * r["epsilon"]],
        "failures": [{k: r[k] for k in ("seed", "layout_seed", "model", "all_reached",
                                         "collisions", "formation_error_max_m")}
                     for r in failed],
    }

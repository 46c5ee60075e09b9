"""Robotarium-style centralized solving, for comparison with the per-robot control steps
(the **central** part of :mod:`experiments.bench`): one QP over every robot's velocity."""

from __future__ import annotations

import logging
import statistics
import time
import warnings
from collections.abc import Sequence

import numpy as np
import qpsolvers
from scipy import sparse

from agent.barriers import Obstacle
from agent.control import Controller, ControlParams, Stall, StepInput, build_rows
from agent.inputs import step_inputs
from experiments.fleet_scenario import fleet_scenario
from experiments.machine import timed
from simulator.inprocess import FleetModel

logger = logging.getLogger(__name__)

CENTRAL_BACKENDS = ("osqp", "clarabel", "daqp", "quadprog")
CENTRAL_BUDGET_S = 3.0  # [s] a backend slower than this on one centralized solve is not repeated


def fleet_snapshot(scenario, speed: float = 0.2) -> tuple[ControlParams, list[StepInput], list]:
    """Every robot's inputs with the fleet at its start, each robot moving at ``speed`` along
    +x (what the in-process simulator hands the control step); also every robot's formation
    name and the formation edges as (i, j, Df) robot indices."""
    fleet = FleetModel.build(scenario)
    robots = scenario.robots
    ctrl = [(r.start[0], r.start[1]) for r in robots]
    vel = [(speed, 0.0)] * len(robots)
    ellipses = fleet.ellipses(ctrl, vel, [r.start[2] for r in robots])
    obs = [Obstacle(o.center[0], o.center[1], o.velocity[0], o.velocity[1], o.safe_distance)
           for o in scenario.obstacles]
    inputs = []
    for i, r in enumerate(robots):
        fname = fleet.formation_of[i]
        gc = scenario.formation_of(r.id).goal_centroid
        # the agent's and the simulator's assembly (agent.inputs), with a fresh jam memory
        step = step_inputs(((*ctrl[j], *vel[j], df) for j, df in fleet.neighbours[i]),
                           ellipses[fname], fname, (gc[0], gc[1]),
                           [(name, e) for name, e in ellipses.items() if name != fname],
                           Stall(), scenario.dt)
        assert step.view is not None  # every formation has its ellipse here
        inputs.append(step._replace(pose=(r.start[0], r.start[1], 0.0), goal=r.goal,
                                    obstacles=obs))
    index = {rid: k for k, rid in enumerate(scenario.robot_ids)}
    edges = [(index[e.i], index[e.j], e.df) for f in scenario.formations for e in f.edges]
    return fleet.params, inputs, edges


# ------------------------------------------------------------------- centralized solving


def central_problem(params: ControlParams, inputs: Sequence[StepInput], formation_of: Sequence[str],
                    edges: Sequence[tuple[int, int, float]], nominal: Sequence[tuple[float, float]]):
    """The centralized QP ``min sum |u_i - nominal_i|^2  s.t.  G u <= h`` over u = (u_1 .. u_N)
    as sparse (P, q, G, h): every robot's speed, obstacle and ellipse rows
    (:func:`agent.control.build_rows` without neighbours), the two band rows of every formation
    edge with both robots' velocities as unknowns (eq. 4.3/4.4), and eq. 3.5 for every pair of
    robots of different formations (Robotarium's pairwise barrier certificate), at distance
    ``params.d_af``. Every row is scaled to a unit gradient per robot block."""
    n = len(inputs)
    rows_i: list[np.ndarray] = []
    cols_i: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    m = 0
    # single-robot rows, by the agent's own row builder
    for i, r in enumerate(inputs):
        built = build_rows(params, r.pose[:2], r.pose[2], nominal[i], r._replace(neighbours=()))
        single = np.array(built.limits + list(built.contact) + built.hard, dtype=float).reshape(-1, 3)
        k = len(single)
        idx = np.arange(m, m + k)
        rows_i += [idx, idx]
        cols_i += [np.full(k, 2 * i), np.full(k, 2 * i + 1)]
        vals += [single[:, 0], single[:, 1]]
        rhs.append(single[:, 2])
        m += k
    p = np.array([r.pose[:2] for r in inputs], dtype=float)

    def coupled(a: np.ndarray, b: np.ndarray, sign: float, h: np.ndarray, gamma: float) -> None:
        """Rows  sign * (-d . u_a + d . u_b) <= gamma h  with d = (p_a - p_b) / |p_a - p_b|."""
        nonlocal m
        d = p[a] - p[b]
        norm = np.hypot(d[:, 0], d[:, 1])
        d = sign * d / norm[:, None]
        k = len(a)
        idx = np.arange(m, m + k)
        for block, s in ((a, -1.0), (b, 1.0)):
            rows_i.extend([idx, idx])
            cols_i.extend([2 * block, 2 * block + 1])
            vals.extend([s * d[:, 0], s * d[:, 1]])
        rhs.append(gamma * h / (2.0 * norm))
        m += k

    if edges:
        e = np.array(edges, dtype=float)
        a, b, df = e[:, 0].astype(int), e[:, 1].astype(int), e[:, 2]
        d2 = np.sum((p[a] - p[b]) ** 2, axis=1)
        eps = params.epsilon
        coupled(a, b, 1.0, d2 - (df - eps) ** 2, params.gamma_formation)  # eq. 4.3
        coupled(a, b, -1.0, (df + eps) ** 2 - d2, params.gamma_formation)  # eq. 4.4
    ia, ib = np.triu_indices(n, 1)
    names = np.array(formation_of)
    foreign = names[ia] != names[ib]
    a, b = ia[foreign], ib[foreign]
    if len(a):
        d2 = np.sum((p[a] - p[b]) ** 2, axis=1)
        coupled(a, b, 1.0, d2 - params.d_af ** 2, params.gamma_formations)  # eq. 3.5
    g = sparse.csc_matrix((np.concatenate(vals), (np.concatenate(rows_i), np.concatenate(cols_i))),
                          shape=(m, 2 * n))
    h = np.concatenate(rhs)
    pm = sparse.identity(2 * n, format="csc") * 2.0
    q = -2.0 * np.array(nominal, dtype=float).reshape(-1)
    return pm, q, g, h


def _solve_central(name: str, pm, q, g, h):
    """One centralized solve by qpsolvers backend ``name`` (sparse or dense as it takes)."""
    opts: dict = {}
    if name == "osqp":
        opts = {"eps_abs": 1e-6, "eps_rel": 1e-6, "polish": True, "verbose": False}
    elif name == "clarabel":
        opts = {"verbose": False}
    if name not in getattr(qpsolvers, "sparse_solvers", ()):
        pm, g = pm.toarray(), g.toarray()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # osqp's future-default notice; answered by the check
        x = qpsolvers.solve_qp(pm, q, g, h, solver=name, **opts)
    if x is None or not np.all(np.isfinite(x)):
        return None
    return x


def bench_central(sizes: Sequence[int], backends: Sequence[str], repeat: int,
                  budget_s: float = CENTRAL_BUDGET_S) -> dict:
    """Centralized QP (build + solve per backend) against N per-robot control steps, per N."""
    out: dict[str, dict] = {}
    for n in sizes:
        scenario = fleet_scenario(n, 0.05, 10.0)
        params, inputs, edges = fleet_snapshot(scenario)
        formation_of = [scenario.formation_of(r).name for r in scenario.robot_ids]

        controller = Controller(params, clock=time.perf_counter_ns)

        def all_steps(controller=controller, inputs=inputs):
            return [controller.step(r) for r in inputs]

        steps = all_steps()
        nominal = [(s.nominal_ux, s.nominal_uy) for s in steps]
        dist_times = timed(all_steps, repeat)
        def build(params: ControlParams = params, inputs: list[StepInput] = inputs,
                  fo: list[str] = formation_of, e: list = edges,
                  nom: list[tuple[float, float]] = nominal) -> object:
            return central_problem(params, inputs, fo, e, nom)

        build_times = timed(build, repeat)
        pm, q, g, h = central_problem(params, inputs, formation_of, edges, nominal)
        entry: dict = {
            "robots": n, "variables": 2 * n, "rows": int(g.shape[0]), "nonzeros": int(g.nnz),
            "per_robot_total_us": statistics.median(dist_times),
            "per_robot_step_us": statistics.median(dist_times) / n,
            "central_build_us": statistics.median(build_times),
            "solve_us": {}, "total_us": {}, "max_violation": {}, "max_diff_vs_per_robot": {},
            "skipped": {},
        }
        u_dist = np.array([(s.ux, s.uy) for s in steps])
        for name in backends:
            if name not in qpsolvers.available_solvers:
                continue
            times = []
            x = None
            for _ in range(repeat):
                t0 = time.perf_counter_ns()
                x = _solve_central(name, pm, q, g, h)
                times.append((time.perf_counter_ns() - t0) * 1e-3)
                if times[-1] > budget_s * 1e6:
                    entry["skipped"][name] = f"one solve took {times[-1] / 1e6:.1f} s: not repeated"
                    break
            med = statistics.median(times)
            entry["solve_us"][name] = med
            entry["total_us"][name] = med + entry["central_build_us"]
            if x is None:
                entry["max_violation"][name] = None
                entry["max_diff_vs_per_robot"][name] = None
            else:
                entry["max_violation"][name] = max(0.0, float(np.max(g @ x - h)))
                entry["max_diff_vs_per_robot"][name] = float(
                    np.max(np.hypot(*(x.reshape(-1, 2) - u_dist).T)))
        out[str(n)] = entry
        logger.info("central N=%d: %s", n, entry["total_us"])
    return out

"""``formation commcost``: the communication cost of the reduced topology against all-to-all.

Thesis section 4.2 claims that letting only the formation leaders exchange one ellipse each, and
hand the others' ellipses to their members, costs less communication than having every robot
avoid every robot of the other formations (the pairwise specification, eq. 3.5). This module
measures that claim on real traffic: for each fleet size it generates a crossing scenario
(:func:`crossing_scenario`), runs it as separate processes over Zenoh in both topologies through
:func:`simulator.launch.launch` (lock-step: deterministic), and compares the deliveries counted at
the agents' subscribers with the counts the topology implies (:func:`analytic_deliveries`).

What is counted
    *Deliveries received* by agents on the inter-robot key classes, the ones the topology decides:
    ``state`` (agent -> agent), ``ellipse`` (leader -> other leaders) and ``others`` (leader -> its
    own members). One put heard by k subscribers is k deliveries. The same definition serves both
    topologies. Per control tick, with N robots, L formations (one leader each), formation sizes
    n_f and E graph edges in all:

    * reduced: ``state`` sum n_f (n_f - 1) (every robot hears every other member of its
      formation: its graph neighbours for the formation rows, the others for the hard separation
      rows; 2E before those rows existed), ``ellipse`` L(L-1), ``others`` N - L (every member
      hears its leader);
    * all-to-all: ``state`` N(N-1) (every robot hears every other robot), ``ellipse`` L(L-1) and
      ``others`` N - L: the leaders still exchange ellipses and hand them to their members,
      because the formation-level tie-break and jam rule read them (without them the baseline
      was a less capable controller); the ellipses give no barrier rows there.

    The all-to-all agent subscribes with one wildcard (``robot/*/state``), and Zenoh also delivers
    each agent's own ``state`` to that subscriber inside its own session: N more deliveries per
    tick that never cross the network. The launcher's ``summary.json`` counts them (its ``comm``
    is every delivery received); the table here subtracts them (``echo`` columns; an agent puts
    exactly one ``state`` per tick, so they equal the ``state`` puts) and keeps the raw numbers.

    Shared by both topologies and not counted: ``pose`` and ``obstacles`` (world -> agents, N
    each per tick) and ``cmd`` (agent -> world, N per tick, plus one zero command per agent on
    exit). They are in the CSV as ``shared_per_tick``. Lifelong operation's orders, bids, votes
    and order status are counted on their own line, ``orders`` (:func:`wire.traffic.orders_line`:
    ``orders_per_tick`` and ``orders_bytes_per_tick``, deliveries received), never in the
    topology's counts; a crossing has none.

Bytes are payload bytes (the Zenoh serialization of :mod:`wire.payloads`), without Zenoh's own
framing; :func:`analytic_bytes` predicts them exactly by encoding messages with the scenario's
formation ids.

The layout (:func:`crossing_scenario`): formations in lanes that cross at right angles, half
east/west, half north/south, alternating directions lane by lane, alternating 2-robot pairs and
4-robot rectangles; each formation starts a different distance before the crossing region so
pairs of formations meet there one encounter at a time rather than all at once.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from geometry.ellipse import Ellipse, within_reach
from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from leader.role import VIEW_RANGE
from scenario import Scenario
from scenario.load import scenario_from_dict
from simulator.launch import launch
from simulator.output import OutputError, write_run
from simulator.run_config import RunConfig
from wire import keys, traffic
from wire.payloads import EllipseMsg, Others, State, encode

logger = logging.getLogger(__name__)

TOPOLOGIES = ("reduced", "all-to-all")
INTER_ROBOT = (keys.STATE, keys.ELLIPSE, keys.OTHERS)  # the classes the topology decides
SHARED = (keys.POSE, keys.CMD, keys.OBSTACLES)  # world <-> agents, the same in both topologies
MIN_FORMATIONS = 2  # a crossing needs two formations
MAX_FORMATIONS = 16  # 48 agent processes: the most this command will start on one machine

# Layout of :func:`crossing_scenario`.
LANE_SPACING = 1.6  # [m] between parallel lanes
EDGE_MARGIN = 1.3  # [m] from the outermost crossing lane to a formation's start or goal
MIN_HALF_CROSSING = 3.5  # [m] a formation starts at least this far before the crossing centre
START_STEP = 0.75  # [m] stagger of the start distances, one step per slot
DURATION = 75.0  # [s] simulated time limit of every run
D_AF = 0.35  # [m] eq. 3.5 distance of the all-to-all baseline: two radii + 0.14 m
# Reference shapes in the formation's own frame (x along travel), leader first; edges by index.
PAIR = (((0.0, 0.25), (0.0, -0.25)), ((0, 1),))
RECTANGLE = (((0.3, 0.15), (0.3, -0.15), (-0.3, -0.15), (-0.3, 0.15)),
             ((0, 1), (0, 2), (0, 3), (1, 2), (2, 3)))

CSV_COLUMNS = (
    "topology", "formations", "robots", "edges", "steps", "sim_time_s",
    "messages_per_robot_per_s", "bytes_per_robot_per_s", "constraints_per_robot",
    "collisions", "all_reached", "time_to_goal_s",
    "analytic_messages_per_robot_per_s", "analytic_bytes_per_robot_per_s",
    "state_per_tick", "ellipse_per_tick", "others_per_tick", "echo_per_tick",
    "analytic_state_per_tick", "analytic_ellipse_per_tick", "analytic_others_per_tick",
    "state_bytes_per_tick", "ellipse_bytes_per_tick", "others_bytes_per_tick",
    "analytic_state_bytes_per_tick", "analytic_ellipse_bytes_per_tick",
    "analytic_others_bytes_per_tick",
    "raw_messages_per_robot_per_s", "raw_bytes_per_robot_per_s", "shared_per_tick",
    "orders_per_tick", "orders_bytes_per_tick",
    "formation_error_max_m", "min_clearance_robot_m", "qp_infeasible_ticks", "stale_ticks",
    "lockstep_timeouts", "wall_s",
)


# --------------------------------------------------------------------------- analytic counts


def _check_fleet(sizes: Sequence[int], edges: Sequence[int], topology: str) -> None:
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology: {topology!r} is not one of {TOPOLOGIES}")
    if len(sizes) != len(edges):
        raise ValueError(f"edges: {len(edges)} counts for {len(sizes)} formations")
    for name, values, least in (("sizes", sizes, 1), ("edges", edges, 0)):
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise ValueError(f"{name}: every entry must be an int >= {least}, got {v!r}")


def analytic_deliveries(sizes: Sequence[int], edges: Sequence[int], topology: str) -> dict[str, int]:
    """Deliveries per control tick on each inter-robot class (see the module docstring).

    ``sizes[f]`` robots and ``edges[f]`` graph edges in formation f (one leader each). The
    all-to-all count excludes the wildcard echo of an agent's own state (:func:`wildcard_echo`).
    """
    _check_fleet(sizes, edges, topology)
    n, formations = sum(sizes), len(sizes)
    members = n - formations  # every robot but the leaders hears its leader's ``others``
    leaders = formations * (formations - 1)
    if topology == "reduced":
        return {keys.STATE: sum(m * (m - 1) for m in sizes), keys.ELLIPSE: leaders,
                keys.OTHERS: members}
    return {keys.STATE: n * (n - 1), keys.ELLIPSE: leaders, keys.OTHERS: members}


def wildcard_echo(n_robots: int, topology: str) -> int:
    """Per tick, the agents' own ``state`` delivered back to their own all-to-all wildcard."""
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology: {topology!r} is not one of {TOPOLOGIES}")
    return n_robots if topology == "all-to-all" else 0


def constraints_per_robot(sizes: Sequence[int], edges: Sequence[int], topology: str) -> float:
    """Mean number of barrier rows in a robot's QP that depend on communication: two formation
    rows per incident edge (eq. 4.3, 4.4), one separation row per other member of its formation,
    plus one row per other formation's ellipse (eq. 4.6, reduced) or two per robot of another
    formation (eq. 3.5 and a separation row, all-to-all). The speed-limit rows and obstacle
    rows, the same in both topologies, are not included."""
    _check_fleet(sizes, edges, topology)
    n, formations = sum(sizes), len(sizes)
    formation_rows = 4 * sum(edges)  # 2 rows at each end of every edge
    separation = sum(s * (s - 1) for s in sizes)
    if topology == "reduced":
        avoid = n * (formations - 1)
    else:
        avoid = 2 * (n * n - sum(s * s for s in sizes))
    return (formation_rows + separation + avoid) / n


def fleet_of(scenario: Scenario) -> tuple[list[int], list[int]]:
    """(robots per formation, edges per formation) of ``scenario``."""
    return ([len(f.robots) for f in scenario.formations], [len(f.edges) for f in scenario.formations])


def analytic_bytes(scenario: Scenario, topology: str,
                   ellipses: Sequence[tuple] | None = None) -> dict[str, int | float]:
    """Payload bytes per control tick on each inter-robot class, from the encoded size of each
    message with the scenario's formation ids (every float field has a fixed size; an ellipse
    carries one point per member).

    A leader's ``others`` holds only the formations within :data:`leader.role.VIEW_RANGE` of its
    ellipse: given the run's ellipses (``series.ellipses`` rows: t, formation, then the
    :class:`geometry.ellipse.Ellipse` fields, as each leader estimated them), the ``others``
    bytes are averaged over its ticks with exactly the formations each leader had in view;
    without them, every other formation counts (the most a tick can carry)."""
    sizes, edges = fleet_of(scenario)
    counts = analytic_deliveries(sizes, edges, topology)
    state = len(encode(State(0.0, 0.0, 0.0, 0.0, 0.0)))

    members = {f.name: len(f.robots) for f in scenario.formations}

    def ellipse(fid: str) -> EllipseMsg:  # with its members' points and headings (version 2)
        return EllipseMsg(fid, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0,
                          ((0.0, 0.0),) * members[fid], (0.0,) * members[fid])

    names = list(members)

    def others_bytes(f: str, in_view: Sequence[str]) -> int:
        msg = Others(f, 0.0, tuple(ellipse(g) for g in in_view), ellipse(f))
        return (members[f] - 1) * len(encode(msg))

    ellipse_bytes = sum((len(names) - 1) * len(encode(ellipse(f))) for f in names)
    if ellipses is None:
        others: int | float = sum(others_bytes(f, [g for g in names if g != f]) for f in names)
    else:
        by_tick: dict[float, dict[str, Ellipse]] = {}
        for row in ellipses:
            by_tick.setdefault(row[0], {})[row[1]] = Ellipse(*row[2:])
        total = 0
        for now in by_tick.values():
            for f, own in now.items():
                total += others_bytes(f, [g for g, e in now.items() if g != f
                                          and within_reach(own, e.cx, e.cy, e.a, VIEW_RANGE)])
        others = total / len(by_tick) if by_tick else 0
    return {keys.STATE: counts[keys.STATE] * state, keys.ELLIPSE: ellipse_bytes,
            keys.OTHERS: others}


# --------------------------------------------------------------------------- scenarios


def _directions(formations: int) -> list[bool]:
    """Per formation, True for an east/west lane: H, V, V, H, H, V, V, H... so that both pair
    and rectangle formations cross in both directions."""
    return [(k // 2 + k) % 2 == 0 for k in range(formations)]


def _stride(formations: int) -> int:
    """A stride coprime with ``formations``: slot ``k * stride % formations`` is a permutation
    that puts neighbouring lanes' start distances far apart."""
    for s in (3, 5, 7, 11, 13):
        if math.gcd(s, formations) == 1:
            return s
    return 1


def crossing_scenario(formations: int, *, duration: float = DURATION, d_af: float = D_AF,
                      start_step: float = START_STEP) -> dict[str, Any]:
    """A crossing of ``formations`` formations as a scenario-file mapping (validate it with
    :func:`scenario.load.scenario_from_dict`).

    Formation k is a pair when k is even and a rectangle when odd (leader ``f{k}r0``). East/west
    and north/south lanes :data:`LANE_SPACING` apart cross around the origin; parallel lanes
    alternate directions. A formation starts ``D + start_step * slot`` before the centre and ends
    ``D`` beyond it, where ``D`` clears the outermost crossing lane by :data:`EDGE_MARGIN` (and is
    at least :data:`MIN_HALF_CROSSING`), and the slots are a permutation of ``0..formations-1``.
    """
    if isinstance(formations, bool) or not isinstance(formations, int) or formations < MIN_FORMATIONS:
        raise ValueError(f"formations: must be an int >= {MIN_FORMATIONS}, got {formations!r}")
    for name, v in (("duration", duration), ("d_af", d_af)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a positive number, got {v!r}")
    if not (isinstance(start_step, int | float) and math.isfinite(start_step) and start_step >= 0):
        raise ValueError(f"start_step: must be a number >= 0, got {start_step!r}")
    horizontal = _directions(formations)
    lanes = {True: [k for k in range(formations) if horizontal[k]],
             False: [k for k in range(formations) if not horizontal[k]]}
    widest = max(len(v) for v in lanes.values())
    half = max(MIN_HALF_CROSSING, (widest - 1) / 2 * LANE_SPACING + EDGE_MARGIN)
    stride = _stride(formations)
    out = []
    for k in range(formations):
        mine = lanes[horizontal[k]]
        i = mine.index(k)
        lateral = (i - (len(mine) - 1) / 2) * LANE_SPACING
        sign = 1.0 if i % 2 == 0 else -1.0
        start_d = half + start_step * ((k * stride) % formations)
        if horizontal[k]:
            heading = 0.0 if sign > 0 else math.pi
            start, goal = (-sign * start_d, lateral), (sign * half, lateral)
        else:
            heading = math.pi / 2 if sign > 0 else -math.pi / 2
            start, goal = (lateral, -sign * start_d), (lateral, sign * half)
        c, s = math.cos(heading), math.sin(heading)
        offsets, edges = PAIR if k % 2 == 0 else RECTANGLE
        name = f"f{k}"
        robots = {}
        for j, (ox, oy) in enumerate(offsets):
            wx, wy = c * ox - s * oy, s * ox + c * oy
            robots[f"{name}r{j}"] = {
                "start": [round(start[0] + wx, 4), round(start[1] + wy, 4)],
                "goal": [round(goal[0] + wx, 4), round(goal[1] + wy, 4)],
            }
        out.append({"name": name, "leader": f"{name}r0", "robots": robots,
                    "edges": [[f"{name}r{a}", f"{name}r{b}"] for a, b in edges]})
    return {
        "name": f"commcost-{formations}",
        "dt": 0.05,
        "duration": float(duration),
        "goal_tolerance": 0.05,
        "robot": {"model": "single_integrator", "max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 1.0, "formations": 0.5},
                       "epsilon": 0.05, "d_af": float(d_af)},
        "formations": out,
        "obstacles": [],
    }


# --------------------------------------------------------------------------- runs


def parse_formations(text: str) -> list[int]:
    """``"2,4,8"`` -> ``[2, 4, 8]`` (sorted, without repeats); ValueError naming ``--formations``."""
    values = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            v = int(part)
        except ValueError:
            raise ValueError(f"--formations: {part!r} is not an integer") from None
        if not MIN_FORMATIONS <= v <= MAX_FORMATIONS:
            raise ValueError(f"--formations: {v} is outside {MIN_FORMATIONS}..{MAX_FORMATIONS}")
        values.append(v)
    return sorted(set(values))


def measure_row(scenario: Scenario, summary: dict, topology: str, wall_s: float,
                ellipses: Sequence[tuple] | None = None) -> dict[str, Any]:
    """One CSV row: measured counts from a multi-process run's ``summary`` next to the analytic
    (``ellipses``: the run's, for the formations each leader had in view; see
    :func:`analytic_bytes`)."""
    sizes, edges = fleet_of(scenario)
    n = sum(sizes)
    steps, sim_time = summary["steps"], summary["sim_time_s"]
    classes = summary["comm"]["classes"]
    recv = {c: classes[c]["recv"] for c in keys.KEY_CLASSES if c in classes}
    orders = traffic.orders_line({"recv": recv})["recv"]
    echo = classes[keys.STATE]["put"]["messages"] if topology == "all-to-all" else 0
    echo_bytes = classes[keys.STATE]["put"]["bytes"] if topology == "all-to-all" else 0
    messages = sum(recv[c]["messages"] for c in INTER_ROBOT) - echo
    nbytes = sum(recv[c]["bytes"] for c in INTER_ROBOT) - echo_bytes
    per = n * sim_time
    counts = analytic_deliveries(sizes, edges, topology)
    nb = analytic_bytes(scenario, topology, ellipses)
    dt = scenario.dt
    state_msgs = recv[keys.STATE]["messages"] - echo
    state_bytes = recv[keys.STATE]["bytes"] - echo_bytes

    def per_tick(v: float) -> float:
        return v / steps if steps else 0.0

    return {
        "topology": topology,
        "formations": len(sizes),
        "robots": n,
        "edges": sum(edges),
        "steps": steps,
        "sim_time_s": sim_time,
        "messages_per_robot_per_s": messages / per if per else 0.0,
        "bytes_per_robot_per_s": nbytes / per if per else 0.0,
        "constraints_per_robot": constraints_per_robot(sizes, edges, topology),
        "collisions": summary["collisions"],
        "all_reached": summary["all_reached"],
        "time_to_goal_s": summary["time_to_goal_s"],
        "analytic_messages_per_robot_per_s": sum(counts.values()) / (n * dt),
        "analytic_bytes_per_robot_per_s": sum(nb.values()) / (n * dt),
        "state_per_tick": per_tick(state_msgs),
        "ellipse_per_tick": per_tick(recv[keys.ELLIPSE]["messages"]),
        "others_per_tick": per_tick(recv[keys.OTHERS]["messages"]),
        "echo_per_tick": per_tick(echo),
        "analytic_state_per_tick": counts[keys.STATE],
        "analytic_ellipse_per_tick": counts[keys.ELLIPSE],
        "analytic_others_per_tick": counts[keys.OTHERS],
        "state_bytes_per_tick": per_tick(state_bytes),
        "ellipse_bytes_per_tick": per_tick(recv[keys.ELLIPSE]["bytes"]),
        "others_bytes_per_tick": per_tick(recv[keys.OTHERS]["bytes"]),
        "analytic_state_bytes_per_tick": nb[keys.STATE],
        "analytic_ellipse_bytes_per_tick": nb[keys.ELLIPSE],
        "analytic_others_bytes_per_tick": nb[keys.OTHERS],
        "raw_messages_per_robot_per_s": summary["comm"]["messages_per_robot_per_s"],
        "raw_bytes_per_robot_per_s": summary["comm"]["bytes_per_robot_per_s"],
        "shared_per_tick": per_tick(sum(recv[c]["messages"] for c in SHARED)),
        "orders_per_tick": per_tick(orders["messages"]),
        "orders_bytes_per_tick": per_tick(orders["bytes"]),
        "formation_error_max_m": summary["formation_error_max_m"],
        "min_clearance_robot_m": summary["min_clearance_m"]["robot"],
        "qp_infeasible_ticks": summary["qp"]["infeasible"],
        "stale_ticks": summary["agents"]["stale"],
        "lockstep_timeouts": summary["agents"]["lockstep_timeouts"],
        "wall_s": round(wall_s, 2),
    }


def run_commcost(
    formations: Sequence[int],
    out: Path,
    *,
    duration: float = DURATION,
    on_run: Callable[[int, int, str, Scenario], Any] | None = None,
    on_done: Callable[[dict[str, Any]], None] | None = None,
    progress_factory: Callable[[], Any] | None = None,
) -> list[dict[str, Any]]:
    """Generate, run (both topologies, multi-process, lock-step) and measure every fleet size.

    Writes ``out/scenarios/commcost-F.yaml`` (replayable with ``formation run``) and each run's
    output under ``out/runs/TOPOLOGY-F/``; returns the CSV rows. ``on_run(index, total, topology,
    scenario)`` is called before a run and ``on_done(row)`` after it; ``progress_factory`` is
    handed to :func:`simulator.launch.launch`.
    """
    out = Path(out)
    (out / "scenarios").mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    total = 2 * len(formations)
    index = 0
    for f in formations:
        mapping = crossing_scenario(f, duration=duration)
        scenario = scenario_from_dict(mapping)
        (out / "scenarios" / f"{scenario.name}.yaml").write_text(
            yaml.safe_dump(mapping, sort_keys=False), encoding="utf-8")
        for topology in TOPOLOGIES:
            index += 1
            if on_run is not None:
                on_run(index, total, topology, scenario)
            run_dir = out / "runs" / f"{topology}-{f}"
            t0 = time.monotonic()
            summary, series = launch(RunConfig(scenario, run_dir, topology=topology),
                                     progress_factory=progress_factory)
            wall = time.monotonic() - t0
            if write_run(summary, series, scenario, run_dir, plots=False):
                raise OutputError(f"cannot write {run_dir}: {summary['lost_files']}")
            row = measure_row(scenario, summary, topology, wall, series.ellipses)
            logger.info("commcost %s F=%d: %s", topology, f, row)
            rows.append(row)
            if on_done is not None:
                on_done(row)
    return rows


# --------------------------------------------------------------------------- outputs


def paired(rows: Sequence[dict[str, Any]]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(reduced row, all-to-all row) per fleet size, by number of formations."""
    by = {(r["formations"], r["topology"]): r for r in rows}
    sizes = sorted({r["formations"] for r in rows})
    return [(by[(f, "reduced")], by[(f, "all-to-all")]) for f in sizes
            if (f, "reduced") in by and (f, "all-to-all") in by]


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(CSV_COLUMNS))
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(r[k]) for k in CSV_COLUMNS})


def _cell(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else ""
    return "" if v is None else v


def ratio(a: float, b: float) -> float:
    return a / b if b else math.nan


def outcome(r: dict[str, Any]) -> str:
    ttg = r["time_to_goal_s"]
    reached = f"reached at {ttg:.1f} s" if r["all_reached"] else "NOT reached"
    return f"{reached}, {r['collisions']} collisions"


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The comparison table (one line per fleet size) and the analytic check per class."""
    lines = [
        "| formations | robots | msgs/robot/s reduced | msgs/robot/s all-to-all | ratio "
        "| bytes/robot/s reduced | bytes/robot/s all-to-all | ratio "
        "| QP rows/robot reduced | QP rows/robot all-to-all | reduced run | all-to-all run |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |",
    ]
    for red, a2a in paired(rows):
        lines.append(
            f"| {red['formations']} | {red['robots']} "
            f"| {red['messages_per_robot_per_s']:.1f} | {a2a['messages_per_robot_per_s']:.1f} "
            f"| {ratio(red['messages_per_robot_per_s'], a2a['messages_per_robot_per_s']):.3f} "
            f"| {red['bytes_per_robot_per_s']:.0f} | {a2a['bytes_per_robot_per_s']:.0f} "
            f"| {ratio(red['bytes_per_robot_per_s'], a2a['bytes_per_robot_per_s']):.3f} "
            f"| {red['constraints_per_robot']:.2f} | {a2a['constraints_per_robot']:.2f} "
            f"| {outcome(red)} | {outcome(a2a)} |")
    lines += [
        "",
        "Deliveries per control tick, measured (analytic), and the wildcard echo measured apart:",
        "",
        "| formations | robots | topology | state | ellipse | others | echo | bytes/tick measured "
        "| bytes/tick analytic | ticks |",
        "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        measured_b = r["state_bytes_per_tick"] + r["ellipse_bytes_per_tick"] + r["others_bytes_per_tick"]
        analytic_b = (r["analytic_state_bytes_per_tick"] + r["analytic_ellipse_bytes_per_tick"]
                      + r["analytic_others_bytes_per_tick"])
        lines.append(
            f"| {r['formations']} | {r['robots']} | {r['topology']} "
            f"| {r['state_per_tick']:g} ({r['analytic_state_per_tick']}) "
            f"| {r['ellipse_per_tick']:g} ({r['analytic_ellipse_per_tick']}) "
            f"| {r['others_per_tick']:g} ({r['analytic_others_per_tick']}) "
            f"| {r['echo_per_tick']:g} | {measured_b:g} | {analytic_b:g} | {r['steps']} |")
    return "\n".join(lines) + "\n"


def write_markdown(rows: Sequence[dict[str, Any]], path: Path) -> None:
    text = ("# Communication cost: reduced topology versus all-to-all\n\n"
            "Deliveries received by agents on `state`, `ellipse` and `others` per robot per "
            "simulated second (the all-to-all wildcard echo of an agent's own state excluded); "
            "payload bytes likewise. Multi-process over Zenoh, lock-step.\n\n"
            + markdown_table(rows))
    Path(path).write_text(text, encoding="utf-8")


PANELS = (("messages_per_robot_per_s", "deliveries per robot per s"),
          ("bytes_per_robot_per_s", "payload bytes per robot per s"))


def plot_series(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str, str], tuple[list[int], list[float]]]:
    """What :func:`plot` draws: ``(figure, topology, "measured" | "analytic")`` -> (robots,
    values), at the fleet sizes measured only. The analytic value is each run's own (its row's
    ``analytic_*``: the ``others`` of the formations each leader had in view, as the tables of
    commcost.md give it), which the measured one equals; no line joins sizes never run."""
    pairs = paired(rows)
    out = {}
    for key, _label in PANELS:
        for idx, topology in enumerate(TOPOLOGIES):
            pts = [p[idx] for p in pairs]
            robots = [r["robots"] for r in pts]
            out[(key, topology, "measured")] = (robots, [r[key] for r in pts])
            out[(key, topology, "analytic")] = (robots, [r[f"analytic_{key}"] for r in pts])
    return out


def plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Messages and bytes per robot per second against fleet size, both topologies, log scale:
    filled markers measured, open ones the analytic model of the same run
    (:func:`plot_series`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = paired(rows)
    measured_sizes = [p[0]["formations"] for p in pairs]
    series = plot_series(rows)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    for ax, (key, label) in zip(axes, PANELS, strict=True):
        for topology, colour, marker in (("reduced", "tab:blue", "o"), ("all-to-all", "tab:red", "s")):
            xs, ys = series[(key, topology, "measured")]
            ax.plot(xs, ys, marker=marker, color=colour, linestyle="none", markersize=7,
                    label=f"{topology}, measured")
            xs, ys = series[(key, topology, "analytic")]
            ax.plot(xs, ys, marker=marker, color=colour, linestyle="none", markersize=12,
                    markerfacecolor="none", label=f"{topology}, analytic")
        for red, a2a in pairs:
            ax.annotate(f"{ratio(red[key], a2a[key]):.2f}x", (red["robots"], red[key]),
                        textcoords="offset points", xytext=(-24, 8), fontsize=8, color="tab:blue")
        ax.set_yscale("log")
        ax.set_xlabel("robots (measured at formations " + ", ".join(map(str, measured_sizes)) + ")")
        ax.set_ylabel(label)
        ax.set_xticks([p[0]["robots"] for p in pairs])
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Inter-robot traffic per robot: reduced topology vs all-to-all "
                 "(labels: reduced / all-to-all)", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(rows: Sequence[dict[str, Any]], out: Path) -> None:
    """``commcost.csv``, ``commcost.md``, ``commcost.png`` and ``commcost.json`` in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, out / "commcost.csv")
    write_markdown(rows, out / "commcost.md")
    plot(rows, out / "commcost.png")
    (out / "commcost.json").write_text(json.dumps(list(rows), indent=2) + "\n", encoding="utf-8")

"""Figures people expect from a run (thesis chapter 5): trajectories and safety functions.

``trajectories.png`` draws the robots and every moving obstacle at the same few instants
("snapshots", labelled ``t=...``), so a path that seems to cross an obstacle can be read against
where the obstacle was at that time; collisions are marked where and when they began. The axes
cover where the robots go (plus a margin), not every obstacle's whole track.
``safety.png`` shows the smallest barrier value of each kind per robot over time.
Under ``controller.localisation: fused`` both show the robots' own estimates beside the truth:
``trajectories.png`` each robot's estimated path (dotted) beside its true one, and
``safety.png`` a panel of each robot's filter error against the truth with its 95 % confidence
radius (the barriers' margin grows with it), the times a robot stood on blind floor shaded.
Blind floor (``world.camera_blind``) is drawn on ``trajectories.png`` as violet boxes.
``motion.png`` shows each robot's commanded speed and the turn of its command from the tick
before, with the reversals (:mod:`simulator.motion`) marked.
"""

from __future__ import annotations

import math
import re
from bisect import bisect_left
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Ellipse, Patch, Polygon
from matplotlib.text import Text
from matplotlib.ticker import FixedLocator, FormatStrFormatter, NullLocator
from matplotlib.transforms import Bbox

from agent.hard_rows import unmet_hard_rows
from geometry.shapes import box
from scenario import Scenario
from scenario.cargo import load_polygon, placed_load
from scenario.routes import start_plan
from scenario.world import blind_at

from .metrics import SafetyMonitor
from .motion import REVERSAL_SPEED, is_reversal, robot_ticks, turn_angle
from .series import ROBOT_COLUMNS, Series

_COL = {name: k for k, name in enumerate(ROBOT_COLUMNS)}
SNAPSHOTS = 5  # instants at which robots, ellipses and moving obstacles are drawn together
MARGIN_M = 0.5  # [m] around the robots' extent (and at least 5 % of the larger span)
OBSTACLE_REACH_M = 0.5  # [m] more, at most, to show whole a static obstacle at the edge
COLLISION_GID = "collision"  # gid of the collision markers (tests find them by it)
BLIND_GID, ESTIMATE_GID = "blind", "estimate"  # and of the blind boxes and estimated paths
LEGEND_SAFE_DISK = "obstacle: disk of radius Ds (safe distance; robot centres stay outside)"
LEGEND_MOVING = "moving obstacle at the snapshot times (its Ds disk; darker = later)"
LEGEND_BODY = "robot body at the snapshot times (radius r)"
LEGEND_ELLIPSE = "formation ellipse at the snapshot times"
LEGEND_LOAD = "load at the snapshot times (placed by the members' rigid fit)"
LEGEND_COLLISION = "collision (where and when it began)"
LEGEND_OBSTACLE_PATH = "moving obstacle's track"
LEGEND_BLIND = "blind floor (the camera sees no robot there)"
LEGEND_ESTIMATE = "robot's own estimate of its path (fused)"
BLIND_COLOR = (0.55, 0.35, 0.75)
LOCALISATION_TITLE = ("localisation (fused): filter error against the truth (solid) and its 95 % "
                      "radius (dashed) [m]; shaded: a robot on blind floor")


def _colors(n: int):
    cmap = plt.get_cmap("tab10" if n <= 10 else "tab20")
    return [cmap(k % cmap.N) for k in range(n)]


def draw_shapes_and_routes(ax, scenario: Scenario, fcolor: dict) -> None:
    """Walls and shelves (filled, with their safe distance dotted) and each formation's route
    (dash-dot from its start centroid through its waypoints, waypoints as diamonds)."""
    for sh in scenario.shapes:
        pts = sh.corners()
        if sh.kind == "segment":
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", color="0.15", lw=2.5,
                    solid_capstyle="butt")
        else:
            ax.add_patch(Polygon(pts, closed=True, color="0.35", alpha=0.6))
        band = [sh.local_to_world(math.copysign(sh.hx, math.cos(a)) + sh.ds * math.cos(a),
                                  math.copysign(sh.hy, math.sin(a)) + sh.ds * math.sin(a))
                for a in (2 * math.pi * (k + 0.5) / 64 for k in range(65))]
        ax.plot([p[0] for p in band], [p[1] for p in band], ":", color="0.3", lw=0.7)
        if len(scenario.shapes) <= 24:
            ax.annotate(sh.name, (sh.cx, sh.cy), fontsize=6, ha="center", va="center", color="0.1")
    for f in scenario.formations:
        route = start_plan(scenario, f).route  # the footprint's under method rigid
        if len(route) < 2:
            continue
        pts = [f.start_centroid, *route]
        c = fcolor.get(f.name, "k")
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "-.", color=c, lw=0.9, alpha=0.8)
        ax.plot([p[0] for p in route[:-1]], [p[1] for p in route[:-1]], "D", color=c, ms=4,
                mfc="none")


# --- time matching -------------------------------------------------------------------------------

def snapshot_times(times: Sequence[float], count: int = SNAPSHOTS) -> list[float]:
    """``count`` instants of ``times`` (sorted, distinct), evenly spread from first to last."""
    if not times:
        return []
    n = len(times)
    picks = {min(n - 1, round(k * (n - 1) / max(1, count - 1))) for k in range(count)}
    return [times[k] for k in sorted(picks)]


def _nearest(times: Sequence[float], t: float) -> float:
    """The element of sorted ``times`` nearest to ``t`` (series may sample slightly differently)."""
    k = bisect_left(times, t)
    if k == 0:
        return times[0]
    if k == len(times):
        return times[-1]
    return times[k] if times[k] - t < t - times[k - 1] else times[k - 1]


def fused(scenario: Scenario) -> bool:
    return scenario.controller.localisation == "fused"


def estimate_tracks(series: Series) -> dict[str, list[tuple[float, float, float, float, float]]]:
    """A fused run's estimates per robot, as (t, its distance from the true position,
    sigma_m, est_x, est_y) for each row that has one (est_x, est_y, sigma_m end each row:
    :data:`simulator.series.LOCALISATION_COLUMNS`)."""
    out: dict[str, list[tuple[float, float, float, float, float]]] = defaultdict(list)
    for row in series.robots:
        ex, ey, sigma = row[-3:]
        if all(isinstance(v, float) and math.isfinite(v) for v in (ex, ey, sigma)):
            err = math.hypot(ex - row[_COL["x"]], ey - row[_COL["y"]])
            out[row[_COL["robot"]]].append((row[_COL["t"]], err, sigma, ex, ey))
    return out


def blind_spans(series: Series, scenario: Scenario) -> list[tuple[float, float]]:
    """The time spans during which some robot's true position lay on blind floor."""
    boxes = scenario.world.camera_blind
    if not boxes:
        return []
    times: dict[float, bool] = {}
    for row in series.robots:
        t = row[_COL["t"]]
        times[t] = times.get(t, False) or blind_at(boxes, row[_COL["x"]], row[_COL["y"]])
    spans: list[tuple[float, float]] = []
    start = None
    ordered = sorted(times)
    for t in ordered:
        if times[t] and start is None:
            start = t
        elif not times[t] and start is not None:
            spans.append((start, t))
            start = None
    if start is not None:
        spans.append((start, ordered[-1]))
    return spans


def _draw_blind(ax, scenario: Scenario) -> None:
    for b in scenario.world.camera_blind:
        ax.add_patch(Polygon(box("blind", b.center, b.size, b.yaw, 0.0).corners(), closed=True,
                             fc=(*BLIND_COLOR, 0.12), ec=(*BLIND_COLOR, 0.8), lw=0.8, ls="--",
                             gid=BLIND_GID))


def _draw_estimates(ax, series: Series, scenario: Scenario, fcolor: dict) -> None:
    """Each fused robot's estimated path, dotted, in its formation's colour."""
    formation_of = {r: f.name for f in scenario.formations for r in f.robot_ids}
    for rid, pts in estimate_tracks(series).items():
        ax.plot([p[3] for p in pts], [p[4] for p in pts], ":", lw=0.9,
                color=fcolor.get(formation_of.get(rid, ""), "k"), gid=ESTIMATE_GID)


def _robot_tracks(series: Series) -> dict[str, list[tuple[float, float, float]]]:
    by_robot: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
    for row in series.robots:
        by_robot[row[_COL["robot"]]].append((row[_COL["t"]], row[_COL["x"]], row[_COL["y"]]))
    return by_robot


# --- collisions -----------------------------------------------------------------------------------

def collision_onsets(series: Series, scenario: Scenario) -> list[dict]:
    """Each collision's onset, found by the run's own :class:`SafetyMonitor` replayed on the series.

    Returns ``{"t", "a", "b", "x", "y"}`` per onset: (x, y) is the midpoint of two robots that
    touched, or the robot's centre when it entered an obstacle's safe distance.
    """
    index = {rid: k for k, rid in enumerate(scenario.robot_ids)}
    poses: dict[float, np.ndarray] = {}
    for row in series.robots:
        t = row[_COL["t"]]
        if t not in poses:
            poses[t] = np.full((len(index), 2), np.nan)
        k = index.get(row[_COL["robot"]])
        if k is not None:
            poses[t][k] = (row[_COL["x"]], row[_COL["y"]])
    obstacles: dict[float, dict[str, tuple[float, float]]] = defaultdict(dict)
    for t, name, x, y, _ds in series.obstacles:
        obstacles[t][name] = (x, y)
    obstacle_times = sorted(obstacles)
    monitor = SafetyMonitor(scenario)
    onsets: list[dict] = []
    for t in sorted(poses):
        pos = poses[t]
        if np.isnan(pos).any():
            continue  # a tick where not every robot was recorded (should not happen)
        if scenario.obstacles:
            seen = obstacles[_nearest(obstacle_times, t)] if obstacle_times else {}
            centres = [seen.get(o.name, o.position(t)) for o in scenario.obstacles]
        else:
            centres = []
        seen_before = len(monitor.collision_log)
        monitor.update(t, pos, centres)
        onsets += [_onset(entry, pos, index) for entry in monitor.collision_log[seen_before:]]
    return onsets


def _onset(entry: dict, pos: np.ndarray, index: dict[str, int]) -> dict:
    """Where a collision-log entry is drawn: a load's point nearest the other (``kind: load``),
    the midpoint of two robots, or the robot that entered an obstacle's safe distance."""
    if entry.get("kind") == "load":
        return {"t": entry["t"], "a": f"load {entry['a']}", "b": entry["b"],
                "x": entry["x"], "y": entry["y"]}
    a = pos[index[entry["a"]]]
    if entry["b"] in index:
        b = pos[index[entry["b"]]]
        x, y = (a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0
    else:
        x, y = a[0], a[1]
    return {"t": entry["t"], "a": entry["a"], "b": entry["b"], "x": float(x), "y": float(y)}


# --- axis limits ----------------------------------------------------------------------------------

def robot_extent(series: Series, scenario: Scenario) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) covered by the robots' bodies, starts and goals."""
    xs = [row[_COL["x"]] for row in series.robots] + [r.goal[0] for r in scenario.robots]
    ys = [row[_COL["y"]] for row in series.robots] + [r.goal[1] for r in scenario.robots]
    r = scenario.robot.radius
    return min(xs) - r, max(xs) + r, min(ys) - r, max(ys) + r


def robot_limits(series: Series, scenario: Scenario) -> tuple[tuple[float, float], tuple[float, float]]:
    """Axis limits: the robots' extent plus :data:`MARGIN_M` (or 5 % of the larger span), grown
    by at most :data:`OBSTACLE_REACH_M` to show whole the static obstacles that reach into it."""
    x0, x1, y0, y1 = robot_extent(series, scenario)
    m = max(MARGIN_M, 0.05 * max(x1 - x0, y1 - y0))
    x0, x1, y0, y1 = x0 - m, x1 + m, y0 - m, y1 + m
    bx0, bx1, by0, by1 = x0, x1, y0, y1
    for o in scenario.obstacles:
        if o.velocity != (0.0, 0.0):
            continue
        (cx, cy), r = o.center, o.safe_distance
        if cx + r < bx0 or cx - r > bx1 or cy + r < by0 or cy - r > by1:
            continue  # off the robots' area
        x0 = min(x0, max(cx - r, bx0 - OBSTACLE_REACH_M))
        x1 = max(x1, min(cx + r, bx1 + OBSTACLE_REACH_M))
        y0 = min(y0, max(cy - r, by0 - OBSTACLE_REACH_M))
        y1 = max(y1, min(cy + r, by1 + OBSTACLE_REACH_M))
    return (x0, x1), (y0, y1)


# --- labels that do not overlap -------------------------------------------------------------------

_OFFSETS = [(round(r * math.cos(math.pi / 2 + k * math.pi / 4)),
             round(r * math.sin(math.pi / 2 + k * math.pi / 4)))
            for r in (15, 28, 42, 56, 72, 90) for k in range(8)]  # [points] rings of tries around a spot


_TIME_LABEL = re.compile(r"^(.*?)t=(\S+)s$")
MERGE_M = 0.3  # [m] time labels of one thing closer than this become one label


def merge_time_labels(labels: list[tuple[float, float, str, object]]
                      ) -> list[tuple[float, float, str, object]]:
    """Join the ``t=...`` labels of one thing (same name and colour) at nearly the same place,
    such as a formation that waited: ``t=75s`` and ``t=112s`` -> ``t=75, 112s``."""
    merged: list[list] = []  # [x, y, prefix, [times], colour]
    others = []
    for x, y, text, color in labels:
        m = _TIME_LABEL.match(text)
        if m is None:
            others.append((x, y, text, color))
            continue
        prefix, t = m.group(1), m.group(2)
        for entry in merged:
            if (entry[2] == prefix and entry[4] == color
                    and math.hypot(entry[0] - x, entry[1] - y) < MERGE_M):
                entry[3].append(t)
                break
        else:
            merged.append([x, y, prefix, [t], color])
    return [(x, y, f"{prefix}t={', '.join(times)}s", color)
            for x, y, prefix, times, color in merged] + others


def _place_labels(fig: Figure, ax, labels: list[tuple[float, float, str, object]]) -> None:
    """Annotate each (x, y, text, colour), trying offsets until it lies inside the axes and
    overlaps no earlier label (failing that, at the nearest offset)."""
    renderer = cast(FigureCanvasAgg, fig.canvas).get_renderer()  # the Agg backend (module top)
    inside = ax.get_window_extent(renderer)
    placed: list[Bbox] = []
    for x, y, text, color in merge_time_labels(labels):
        chosen = None
        for dx, dy in _OFFSETS:
            ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                              fontsize=6.5, ha="center", va="center", color=color,
                              bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none",
                                    "alpha": 0.75},
                              arrowprops={"arrowstyle": "-", "color": color, "lw": 0.4})
            ann.update_positions(renderer)
            box = Text.get_window_extent(ann, renderer).expanded(1.05, 1.1)  # text, not arrow
            within = (inside.x0 <= box.x0 and box.x1 <= inside.x1
                      and inside.y0 <= box.y0 and box.y1 <= inside.y1)
            if within and not any(box.overlaps(other) for other in placed):
                chosen = box
                break
            ann.remove()
        if chosen is None:  # every place taken: next to its point rather than dropped
            ann = ax.annotate(text, (x, y), xytext=_OFFSETS[0], textcoords="offset points",
                              fontsize=6.5, ha="center", va="center", color=color)
            ann.update_positions(renderer)
            chosen = Text.get_window_extent(ann, renderer)
        placed.append(chosen)


# --- the trajectories figure ----------------------------------------------------------------------

def _draw_obstacles(ax, series: Series, scenario: Scenario) -> None:
    """Static obstacles: their safe-distance disk, named when there are few."""
    moving = {o.name for o in scenario.obstacles if o.velocity != (0.0, 0.0)}
    few = len(scenario.obstacles) <= 6
    for o in scenario.obstacles:
        if o.name in moving:
            continue
        ax.add_patch(Circle(o.center, o.safe_distance, color="0.45", alpha=0.35, lw=0))
        if few:
            ax.annotate(o.name, o.center, fontsize=7, ha="center", va="center")


def _draw_snapshots(ax, series: Series, scenario: Scenario, fcolor: dict,
                    snaps: list[float]) -> list[tuple[float, float, str, object]]:
    """Robots, ellipses and moving obstacles at the same instants; returns the labels to place."""
    labels: list[tuple[float, float, str, object]] = []
    if not snaps:
        return labels
    robot_times = sorted({row[_COL["t"]] for row in series.robots})
    robot_at = {_nearest(robot_times, t): t for t in snaps}
    formation_of = {r: f.name for f in scenario.formations for r in f.robot_ids}
    bodies: dict[float, dict[str, list[tuple[float, float]]]] = defaultdict(lambda: defaultdict(list))
    for row in series.robots:
        if row[_COL["t"]] in robot_at:
            fname = formation_of.get(row[_COL["robot"]], "")
            bodies[robot_at[row[_COL["t"]]]][fname].append((row[_COL["x"]], row[_COL["y"]]))
    for t, by_formation in bodies.items():
        for fname, pts in by_formation.items():
            c = fcolor.get(fname, "k")
            for p in pts:
                ax.add_patch(Circle(p, scenario.robot.radius, fc=c, ec=c, alpha=0.25, lw=0.6))
            _draw_load(ax, scenario, fname, pts, c)
            cx = sum(p[0] for p in pts) / len(pts)
            cy = sum(p[1] for p in pts) / len(pts)
            labels.append((cx, cy, f"t={t:.0f}s", c))
    _draw_ellipses(ax, series, fcolor, snaps)
    return labels + _draw_moving(ax, series, scenario, snaps)


def _draw_ellipses(ax, series: Series, fcolor: dict, snaps: list[float]) -> None:
    """The formations' ellipses at the recorded instants nearest the snapshots."""
    ellipse_times = sorted({row[0] for row in series.ellipses})
    if ellipse_times:
        ellipse_at = {_nearest(ellipse_times, t) for t in snaps}
        for row in series.ellipses:
            t, name, cx, cy, alpha, a, b = row[:7]
            if t in ellipse_at:
                ax.add_patch(Ellipse((cx, cy), 2 * a, 2 * b, angle=math.degrees(alpha), fill=False,
                                     ls="--", lw=0.9, color=fcolor.get(name, "k")))


def _draw_moving(ax, series: Series, scenario: Scenario,
                 snaps: list[float]) -> list[tuple[float, float, str, object]]:
    """Moving obstacles at the snapshots and their tracks; returns their labels."""
    labels: list[tuple[float, float, str, object]] = []
    moving = {o.name for o in scenario.obstacles if o.velocity != (0.0, 0.0)}
    obstacle_times = sorted({row[0] for row in series.obstacles})
    if moving and obstacle_times:
        obstacle_at = {_nearest(obstacle_times, t): t for t in snaps}
        track: dict[str, list[tuple[float, float]]] = defaultdict(list)
        for t, name, x, y, ds in series.obstacles:
            if name not in moving:
                continue
            track[name].append((x, y))
            if t in obstacle_at:
                k = sorted(obstacle_at).index(t)
                shade = 0.75 - 0.55 * k / max(1, len(obstacle_at) - 1)  # later = darker
                ax.add_patch(Circle((x, y), ds, fc=str(shade), ec="0.15", alpha=0.35, lw=0.6))
                labels.append((x, y, f"{name} t={obstacle_at[t]:.0f}s", "0.15"))
        for pts in track.values():
            ax.plot([p[0] for p in pts], [p[1] for p in pts], ":", color="0.3", lw=0.8)
    return labels


def _draw_load(ax, scenario: Scenario, fname: str, pts: list[tuple[float, float]], color) -> None:
    """The formation's load placed at its members' body positions ``pts`` (member order)."""
    f = next((f for f in scenario.formations if f.name == fname), None)
    if f is None or len(pts) != len(f.robots):
        return
    outline = load_polygon(f)
    if not outline:
        return
    placed = placed_load(f, outline, pts)
    if len(placed) == 2:
        ax.plot([p[0] for p in placed], [p[1] for p in placed], "-", color=color, lw=2.5,
                alpha=0.35, solid_capstyle="butt")
    else:
        ax.add_patch(Polygon(placed, closed=True, fc=color, ec=color, alpha=0.12, lw=0.8,
                             hatch="//" if f.load else None))


COLLISIONS_LISTED = 8  # the rest are counted


def _mark_collisions(ax, onsets: list[dict], labels: list) -> None:
    """A red X at each collision's onset, numbered; the numbers are explained in a corner box."""
    lines = []
    for k, c in enumerate(onsets, start=1):
        ax.plot(c["x"], c["y"], "X", color="red", ms=10, mec="darkred", mew=0.8, zorder=5,
                gid=COLLISION_GID)
        labels.append((c["x"], c["y"], str(k), "red"))
        if k <= COLLISIONS_LISTED:
            lines.append(f"{k}: {c['a']} / {c['b']} at t={c['t']:.2f} s")
    if len(onsets) > COLLISIONS_LISTED:
        lines.append(f"... and {len(onsets) - COLLISIONS_LISTED} more")
    if lines:
        ax.text(0.005, 0.01, "collisions (onset)\n" + "\n".join(lines), transform=ax.transAxes,
                fontsize=6.5, color="darkred", va="bottom", ha="left", zorder=6,
                bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "red", "alpha": 0.85})


def _legend_handles(scenario: Scenario, fcolor: dict, collided: bool) -> list:
    handles: list = [Line2D([], [], color=fcolor[f.name], lw=1.2, label=f"formation {f.name} path")
                     for f in scenario.formations]
    handles += [Line2D([], [], ls="", marker="o", color="0.3", ms=5, label="start"),
                Line2D([], [], ls="", marker="x", color="0.3", ms=7, mew=2, label="goal"),
                Patch(fc="0.3", alpha=0.25, label=LEGEND_BODY),
                Line2D([], [], ls="--", color="0.3", lw=0.9, label=LEGEND_ELLIPSE)]
    if any(len(f.robots) >= 2 or f.load for f in scenario.formations):
        handles.append(Patch(fc="0.3", alpha=0.12, label=LEGEND_LOAD))
    if any(o.velocity == (0.0, 0.0) for o in scenario.obstacles):
        handles.append(Patch(fc="0.45", alpha=0.35, label=LEGEND_SAFE_DISK))
    if any(o.velocity != (0.0, 0.0) for o in scenario.obstacles):
        handles += [Patch(fc="0.5", ec="0.15", alpha=0.35, label=LEGEND_MOVING),
                    Line2D([], [], ls=":", color="0.3", lw=0.8, label=LEGEND_OBSTACLE_PATH)]
    if scenario.world.camera_blind:
        handles.append(Patch(fc=(*BLIND_COLOR, 0.12), ec=BLIND_COLOR, ls="--", label=LEGEND_BLIND))
    if fused(scenario):
        handles.append(Line2D([], [], ls=":", color="0.3", lw=0.9, label=LEGEND_ESTIMATE))
    if collided:
        handles.append(Line2D([], [], ls="", marker="X", color="red", ms=9, label=LEGEND_COLLISION))
    return handles


def trajectory_figure(series: Series, scenario: Scenario) -> Figure:
    """The trajectories figure (not saved): see the module docstring."""
    by_robot = _robot_tracks(series)
    formations = [f.name for f in scenario.formations]
    fcolor = dict(zip(formations, _colors(len(formations)), strict=True))
    snaps = snapshot_times(sorted({row[_COL["t"]] for row in series.robots}))

    if series.robots:
        xlim, ylim = robot_limits(series, scenario)
    else:
        xlim, ylim = (-1.0, 1.0), (-1.0, 1.0)
    width = 9.0  # [in] of the axes; the height follows the robots' extent, within reason
    height = min(9.0, max(2.8, width * (ylim[1] - ylim[0]) / (xlim[1] - xlim[0])))
    handles = _legend_handles(scenario, fcolor, collided=False)  # a collision adds one row at most
    legend_h = 0.9 + 0.17 * math.ceil((len(handles) + 1) / 2)
    fig, ax = plt.subplots(figsize=(width, height + legend_h), layout="constrained")
    for f in scenario.formations:
        c = fcolor[f.name]
        for r in f.robots:
            pts = by_robot.get(r.id, [])
            if not pts:
                continue
            ax.plot([p[1] for p in pts], [p[2] for p in pts], "-", color=c, lw=1.0, alpha=0.85)
            ax.plot(pts[0][1], pts[0][2], "o", color=c, ms=4)
            ax.plot(r.goal[0], r.goal[1], "x", color=c, ms=6, mew=1.5)
    _draw_obstacles(ax, series, scenario)
    _draw_blind(ax, scenario)
    if fused(scenario):
        _draw_estimates(ax, series, scenario, fcolor)
    draw_shapes_and_routes(ax, scenario, fcolor)
    labels = _draw_snapshots(ax, series, scenario, fcolor, snaps)
    onsets = collision_onsets(series, scenario)
    _mark_collisions(ax, onsets, labels)

    ax.set_aspect("equal", adjustable="box")  # the limits stay those of the robots
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{scenario.name}: trajectories; robots, ellipses and moving obstacles drawn at "
                 "the same instants", fontsize=10)
    ax.grid(True, lw=0.3)
    fig.legend(handles=_legend_handles(scenario, fcolor, bool(onsets)), fontsize=7, ncol=2,
               loc="outside lower center")
    fig.canvas.draw()  # lays out the axes (equal aspect) so the labels can be placed in it
    _place_labels(fig, ax, labels)
    return fig


def plot_trajectories(series: Series, scenario: Scenario, path: Path) -> None:
    fig = trajectory_figure(series, scenario)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


# --- the safety figure ----------------------------------------------------------------------------

SAFETY_KINDS = (("h_formation", "formation maintenance  h (eq. 4.3/4.4) [m²]"),
                ("h_obstacle", "obstacle avoidance  h (eq. 4.5) [m²]"),
                ("h_formations", "other formations  h (eq. 4.6)"))
MAX_ROBOT_LEGEND = 16  # more robots than this: colour and label by formation


def symlog_scale(values: Sequence[float]) -> tuple[float, tuple[float, float]] | None:
    """(linthresh, ylim) for a symlog axis fitted to ``values``, or None when linear suits them.

    Linear suits values within a factor 20 of their low positive values (1st percentile). Otherwise
    those values set the linear band (at least 1e-4 of the largest), and the axis starts just below
    the smallest value (or just below 0 when none is negative), so no empty band is drawn.
    """
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=float)
    if v.size == 0:
        return None
    top, low = float(v.max()), float(v.min())
    pos = v[v > 0]
    if top <= 0 or pos.size == 0:
        return None
    # Negative values (violations) stay in the linear band, where they read as they are.
    linthresh = max(float(np.percentile(pos, 1)), -low, top * 1e-4)
    if top < 20.0 * linthresh:
        return None  # close to one decade: a linear axis reads better
    linthresh = 10.0 ** math.floor(math.log10(linthresh))  # a decade, so it gets a round tick
    bottom = low * 1.3 if low < 0 else -0.1 * linthresh
    return linthresh, (bottom, top * 1.5)


def symlog_ticks(linthresh: float, ylim: tuple[float, float]) -> list[float]:
    """0, one round tick below it when the axis goes negative, and the decades above linthresh."""
    low, top = ylim
    ticks = [0.0]
    if low < -0.5 * linthresh:  # real negative values, not the small pad below 0
        mag = 10.0 ** math.floor(math.log10(-low))
        ticks.insert(0, -mag * math.floor(-low / mag))
    k = math.ceil(math.log10(linthresh))
    while 10.0**k <= top:
        ticks.append(10.0**k)
        k += 1
    return ticks


def safety_figure(series: Series, scenario: Scenario) -> Figure:
    """The safety figure (not saved): one panel per barrier kind that has values."""
    by_robot: defaultdict[str, defaultdict[str, list]] = defaultdict(lambda: defaultdict(list))
    for row in series.robots:
        rid = row[_COL["robot"]]
        for key, _ in SAFETY_KINDS:
            by_robot[rid][key].append((row[_COL["t"]], row[_COL[key]]))
    present = [(k, label) for k, label in SAFETY_KINDS
               if any(isinstance(v, float) and math.isfinite(v)
                      for r in by_robot.values() for _, v in r[k])]
    if not present:
        present = list(SAFETY_KINDS[:1])
    by_formation = len(scenario.robot_ids) > MAX_ROBOT_LEGEND
    formation_of = {r: f.name for f in scenario.formations for r in f.robot_ids}
    if by_formation:
        names = [f.name for f in scenario.formations]
        colour = dict(zip(names, _colors(len(names)), strict=True))
        robot_colour = {rid: colour[formation_of[rid]] for rid in scenario.robot_ids}
    else:
        robot_colour = dict(zip(scenario.robot_ids, _colors(len(scenario.robot_ids)), strict=True))

    unmet = hard_row_ticks(series)
    panels = len(present) + fused(scenario)
    fig, axes = plt.subplots(panels, 1, figsize=(10, 2.6 * panels + 0.6), sharex=True,
                             squeeze=False)
    handles: dict[str, Line2D] = {}
    for ax, (key, label) in zip(axes[:, 0], present, strict=False):
        values: list[float] = []
        for rid in scenario.robot_ids:
            pts = [(t, v) for t, v in by_robot[rid][key] if isinstance(v, float) and math.isfinite(v)]
            if not pts:
                continue
            name = formation_of[rid] if by_formation else rid
            (line,) = ax.plot([p[0] for p in pts], [p[1] for p in pts], lw=1.0,
                              color=robot_colour[rid])
            handles.setdefault(f"formation {name}" if by_formation else name, line)
            values.extend(p[1] for p in pts)
        label = _mark_unmet(ax, key, label, unmet)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_ylabel("min h")
        ax.set_title(label, fontsize=9)
        scale = symlog_scale(values)
        if scale is not None:
            linthresh, ylim = scale
            ax.set_yscale("symlog", linthresh=linthresh, linscale=1.5)
            ax.set_ylim(*ylim)
            ax.yaxis.set_major_locator(FixedLocator(symlog_ticks(linthresh, ylim)))
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.yaxis.set_minor_locator(NullLocator())
        ax.grid(True, lw=0.3)
    if fused(scenario):
        _localisation_panel(axes[-1, 0], series, scenario, robot_colour)
    axes[-1, 0].set_xlabel("t [s]")
    total = len({(m[0], m[3]) for m in unmet})
    fig.suptitle(f"{scenario.name}: smallest safety function of each kind per robot "
                 f"(safe while >= 0, black line); robot-ticks with a hard row not met: {total}",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.84, 1))
    fig.legend(list(handles.values()), list(handles.keys()), fontsize=7, loc="upper left",
               bbox_to_anchor=(0.845, 0.93), title="robot" if not by_formation else None,
               title_fontsize=7)
    return fig


def _localisation_panel(ax, series: Series, scenario: Scenario, robot_colour: dict) -> None:
    """Each robot's filter error against the truth (solid) and its 95 % radius (dashed)."""
    for t0, t1 in blind_spans(series, scenario):
        ax.axvspan(t0, t1, color=BLIND_COLOR, alpha=0.12, lw=0, gid=BLIND_GID)
    for rid, pts in estimate_tracks(series).items():
        c = robot_colour.get(rid, "k")
        ts = [p[0] for p in pts]
        ax.plot(ts, [p[1] for p in pts], lw=1.0, color=c)
        ax.plot(ts, [p[2] for p in pts], lw=0.8, ls="--", color=c, gid=ESTIMATE_GID)
    ax.set_ylim(bottom=0.0)
    ax.set_ylabel("[m]")
    ax.set_title(LOCALISATION_TITLE, fontsize=9)
    ax.grid(True, lw=0.3)


def plot_safety(series: Series, scenario: Scenario, path: Path) -> None:
    fig = safety_figure(series, scenario)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mark_unmet(ax, key: str, label: str,
                unmet: list[tuple[float, dict[str, float], tuple[str, ...], str]]) -> str:
    """Red crosses on ``ax`` at the ticks on which a hard row was not met (a barrier of this
    kind below zero, or a fallback/failed QP, shown on the hard kinds); the panel title says
    how many."""
    marks = [m for m in unmet if key[2:] in m[2]
             or (key != "h_formation" and {"fallback", "failed"} & set(m[2]))]
    if not marks:
        return label
    ax.plot([m[0] for m in marks], [m[1].get(key, 0.0) for m in marks], "x", color="red",
            ms=6, mew=1.5, label="hard row not met", zorder=5)
    return label + f"  [hard row not met: {len({m[0] for m in marks})} ticks, red x]"


def hard_row_ticks(series: Series) -> list[tuple[float, dict[str, float], tuple[str, ...], str]]:
    """Every robot row of ``series`` on which a hard row was not met: (t, its finite h values
    by column, the reasons of :func:`agent.hard_rows.unmet_hard_rows`, robot)."""
    out = []
    for row in series.robots:
        h = {k: row[_COL[k]] for k in ("h_obstacle", "h_formations")}
        status = row[_COL["status"]]
        kinds = unmet_hard_rows(status if isinstance(status, str) else None, h)
        if kinds:
            finite = {k: v for k, v in (*h.items(), ("h_formation", row[_COL["h_formation"]]))
                      if isinstance(v, float) and math.isfinite(v)}
            out.append((row[_COL["t"]], finite, kinds, row[_COL["robot"]]))
    return out


# --- the motion figure ----------------------------------------------------------------------------

REVERSAL_GID = "reversal"  # gid of the reversal markers (tests find them by it)


def motion_figure(series: Series, scenario: Scenario) -> Figure:
    """Each robot's commanded speed |u| and the turn of its command from the tick before (both
    at least the reversal speed), reversals marked with a red x (:mod:`simulator.motion`)."""
    ticks = robot_ticks(series.robots, ROBOT_COLUMNS, scenario)
    formation_of = {r: f.name for f in scenario.formations for r in f.robot_ids}
    many = len(ticks) > MAX_ROBOT_LEGEND
    colors = dict(zip(ticks, _colors(len(ticks)), strict=True))
    fcolor = dict(zip([f.name for f in scenario.formations], _colors(len(scenario.formations)),
                      strict=True))
    fig, (ax_v, ax_turn) = plt.subplots(2, 1, figsize=(9.0, 6.0), sharex=True, layout="constrained")
    total = 0
    for rid, seq in ticks.items():
        c = fcolor[formation_of.get(rid, "")] if many else colors[rid]
        ts = [k.t for k in seq]
        ax_v.plot(ts, [math.hypot(k.ux, k.uy) for k in seq], lw=0.7, color=c,
                  label=None if many else rid)
        turn = [(b.t, math.degrees(turn_angle((a.ux, a.uy), (b.ux, b.uy))))
                for a, b in zip(seq, seq[1:], strict=False)
                if math.hypot(a.ux, a.uy) >= REVERSAL_SPEED and math.hypot(b.ux, b.uy) >= REVERSAL_SPEED]
        ax_turn.plot([p[0] for p in turn], [p[1] for p in turn], ".", ms=1.5, color=c)
        rev = [b.t for a, b in zip(seq, seq[1:], strict=False)
               if is_reversal((a.ux, a.uy), (b.ux, b.uy))]
        total += len(rev)
        if rev:
            ax_v.plot(rev, [0.0] * len(rev), "x", color="red", ms=5, gid=REVERSAL_GID)
            ax_turn.plot(rev, [180.0] * len(rev), "x", color="red", ms=5, gid=REVERSAL_GID)
    ax_turn.axhline(120.0, color="red", lw=0.6, ls="--")
    ax_v.set_ylabel("|u| [m/s]")
    ax_turn.set_ylabel("turn of u from the tick before [deg]")
    ax_turn.set_ylim(0.0, 185.0)
    ax_turn.set_xlabel("t [s]")
    ax_v.set_title(f"{scenario.name}: commanded speed and turn per tick; {total} reversals "
                   f"(> 120 deg at >= {REVERSAL_SPEED} m/s, red x)", fontsize=10)
    for ax in (ax_v, ax_turn):
        ax.grid(True, lw=0.3)
    if many:
        ax_v.legend(handles=[Line2D([], [], color=fcolor[f.name], label=f"formation {f.name}")
                             for f in scenario.formations], fontsize=7, ncol=4)
    elif ticks:
        ax_v.legend(fontsize=7, ncol=4)
    return fig


def plot_motion(series: Series, scenario: Scenario, path: Path) -> None:
    fig = motion_figure(series, scenario)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)

"""Figures people expect from a run (thesis chapter 5): trajectories and safety functions."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Circle, Ellipse, Polygon  # noqa: E402

from scenario import Scenario  # noqa: E402
from scenario.routes import initial_route  # noqa: E402

from .inprocess import ROBOT_COLUMNS, Series  # noqa: E402

_COL = {name: k for k, name in enumerate(ROBOT_COLUMNS)}
SNAPSHOTS = 5  # ellipse snapshots along the run


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
        route = initial_route(scenario, f)
        if len(route) < 2:
            continue
        pts = [f.start_centroid, *route]
        c = fcolor.get(f.name, "k")
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "-.", color=c, lw=0.9, alpha=0.8)
        ax.plot([p[0] for p in route[:-1]], [p[1] for p in route[:-1]], "D", color=c, ms=4,
                mfc="none")


def plot_trajectories(series: Series, scenario: Scenario, path: Path) -> None:
    by_robot = defaultdict(list)
    for row in series.robots:
        by_robot[row[_COL["robot"]]].append((row[_COL["t"]], row[_COL["x"]], row[_COL["y"]]))
    formations = [f.name for f in scenario.formations]
    fcolor = dict(zip(formations, _colors(len(formations)), strict=True))
    times = sorted({row[0] for row in series.ellipses})
    snap_t = set()
    if times:
        for k in range(SNAPSHOTS):
            snap_t.add(times[min(len(times) - 1, round(k * (len(times) - 1) / max(1, SNAPSHOTS - 1)))])

    fig, ax = plt.subplots(figsize=(9, 6.5))
    for f in scenario.formations:
        c = fcolor[f.name]
        for r in f.robots:
            pts = by_robot.get(r.id, [])
            if not pts:
                continue
            ax.plot([p[1] for p in pts], [p[2] for p in pts], "-", color=c, lw=1.2, alpha=0.85)
            ax.plot(pts[0][1], pts[0][2], "o", color=c, ms=5)
            ax.plot(r.goal[0], r.goal[1], "x", color=c, ms=7, mew=2)
            ax.add_patch(Circle(pts[-1][1:], scenario.robot.radius, fill=False, color=c, lw=0.8))
        ax.plot([], [], "-", color=c, label=f"formation {f.name}")
    for row in series.ellipses:
        t, name, cx, cy, alpha, a, b = row[:7]
        if t in snap_t:
            ax.add_patch(Ellipse((cx, cy), 2 * a, 2 * b, angle=math.degrees(alpha), fill=False,
                                 ls="--", lw=0.9, color=fcolor.get(name, "k")))
            ax.annotate(f"t={t:.0f}s", (cx, cy), fontsize=6, ha="center", color="0.3")
    seen = set()
    for t, name, x, y, ds in series.obstacles:
        if name not in seen:
            ax.add_patch(Circle((x, y), ds, color="0.5", alpha=0.35))
            seen.add(name)
        if t in snap_t:
            ax.add_patch(Circle((x, y), ds, fill=False, color="0.4", lw=0.6, ls=":"))
    last = {}
    for _t, name, x, y, ds in series.obstacles:
        last[name] = (x, y, ds)
    moving = {o.name for o in scenario.obstacles if o.velocity != (0.0, 0.0)}
    for name, (x, y, ds) in last.items():
        ax.add_patch(Circle((x, y), ds, color="0.2", alpha=0.5))
        if name in moving or len(last) <= 6:
            ax.annotate(name, (x, y), fontsize=7, ha="center", va="center")
    draw_shapes_and_routes(ax, scenario, fcolor)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{scenario.name}: trajectories (o start, x goal, dashed: ellipse snapshots)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_safety(series: Series, scenario: Scenario, path: Path) -> None:
    kinds = [("h_formation", "formation maintenance  h (eq. 4.3/4.4) [m²]"),
             ("h_obstacle", "obstacle avoidance  h (eq. 4.5) [m²]"),
             ("h_formations", "other formations  h (eq. 4.6)")]
    by_robot: defaultdict[str, defaultdict[str, list]] = defaultdict(lambda: defaultdict(list))
    for row in series.robots:
        rid = row[_COL["robot"]]
        for key, _ in kinds:
            v = row[_COL[key]]
            by_robot[rid][key].append((row[_COL["t"]], v))
    present = [(k, label) for k, label in kinds
               if any(math.isfinite(v) for r in by_robot.values() for _, v in r[k])]
    if not present:
        present = kinds[:1]
    fig, axes = plt.subplots(len(present), 1, figsize=(9, 2.8 * len(present)), sharex=True,
                             squeeze=False)
    colors = _colors(len(scenario.robot_ids))
    for ax, (key, label) in zip(axes[:, 0], present, strict=True):
        for c, rid in zip(colors, scenario.robot_ids, strict=True):
            pts = [(t, v) for t, v in by_robot[rid][key] if math.isfinite(v)]
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], lw=1.0, color=c, label=rid)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_ylabel("min h")
        ax.set_title(label, fontsize=9)
        if key == "h_formations":
            ax.set_yscale("symlog", linthresh=1.0)
        ax.grid(True, lw=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if len(labels) <= 16:
        axes[0, 0].legend(handles, labels, fontsize=7, ncol=min(8, len(labels)), loc="upper right")
    fig.suptitle(f"{scenario.name}: safety functions per robot (must stay >= 0)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

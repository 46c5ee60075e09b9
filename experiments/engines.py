"""Both engines on one scenario: the kinematic world and MuJoCo side by side.

    python -m experiments.engines SCENARIO... --out DIR [--realtime]

For each scenario it runs ``formation sim`` in the kinematic engine and ``formation sim
--engine mujoco`` (or, with ``--realtime``, ``formation run --realtime --engine mujoco``) into
``DIR/<scenario>/kinematic`` and ``DIR/<scenario>/mujoco``, and prints one markdown row per
scenario: every goal, the monitor's collisions (a centre inside a safe distance, bodies or loads
overlapping), MuJoCo's body contacts, the worst formation error in epsilon, the time to goal,
and whether each robot passed every obstacle on the same side in both engines.

**Same side.** A robot's path passes an obstacle on one side or the other; two paths between
the same start and goal pass it on the same side when they wind around it by the same angle.
The winding angle of a path around a point c is the sum of the signed turns of p(t) - c(t)
from tick to tick (c(t) a moving circle's centre at that tick; a wall's or shelf's centre).
Two runs end within ``goal_tolerance`` of the same goal, so their windings differ by a multiple
of 2 pi plus the small angle their end points subtend: a pair (robot, obstacle) is on the same
side when the two windings differ by less than pi. That compares homotopy classes of the paths
in the plane with the obstacle's reference point removed, for every robot and every obstacle,
and the same for every robot around every other formation's centroid path (which side of a
formation it met it passed).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from scenario import Scenario, load_scenario

Point = tuple[float, float]


def winding(path: Sequence[Point], centres: Sequence[Point]) -> float:
    """The signed angle [rad] that ``path[k] - centres[k]`` turns through from first to last
    point (counter-clockwise positive); each step's turn is taken in (-pi, pi]."""
    total = 0.0
    prev: float | None = None
    for (x, y), (cx, cy) in zip(path, centres, strict=True):
        dx, dy = x - cx, y - cy
        if dx == 0.0 and dy == 0.0:
            continue  # on the point itself: no direction (then the next step turns through it)
        a = math.atan2(dy, dx)
        if prev is not None:
            total += math.atan2(math.sin(a - prev), math.cos(a - prev))
        prev = a
    return total


@dataclass(frozen=True)
class Run:
    """What one engine's run left: its summary and each robot's body path with its times."""

    summary: dict
    times: dict[str, list[float]]
    paths: dict[str, list[Point]]
    formation_of: dict[str, str]

    @classmethod
    def read(cls, out: Path) -> Run:
        times: dict[str, list[float]] = {}
        paths: dict[str, list[Point]] = {}
        formation_of: dict[str, str] = {}
        with (out / "robots.csv").open(newline="") as f:
            for row in csv.DictReader(f):
                times.setdefault(row["robot"], []).append(float(row["t"]))
                paths.setdefault(row["robot"], []).append((float(row["x"]), float(row["y"])))
                formation_of[row["robot"]] = row["formation"]
        return cls(json.loads((out / "summary.json").read_text()), times, paths, formation_of)

    def centroids(self) -> dict[str, list[Point]]:
        """Each formation's centroid path (its members' mean body position, tick by tick)."""
        out = {}
        for name in set(self.formation_of.values()):
            members = [self.paths[r] for r, f in self.formation_of.items() if f == name]
            out[name] = [(sum(p[0] for p in ps) / len(ps), sum(p[1] for p in ps) / len(ps))
                         for ps in zip(*members, strict=True)]
        return out


def obstacle_centres(scenario: Scenario, times: Sequence[float]) -> dict[str, list[Point]]:
    """Every obstacle's reference point at ``times``: a circle's centre (moving ones move), a
    wall's or shelf's centre."""
    out = {o.name: [o.position(t) for t in times] for o in scenario.obstacles}
    out.update({s.name: [(s.cx, s.cy)] * len(times) for s in scenario.shapes})
    return out


def windings(scenario: Scenario, run: Run) -> dict[tuple[str, str], float]:
    """(robot, obstacle) -> the robot's path's winding angle around the obstacle, and (robot,
    formation) -> around every other formation's centroid path (which side of a formation
    coming the other way it passed)."""
    out = {}
    centroids = run.centroids()
    for rid, path in run.paths.items():
        for name, centres in obstacle_centres(scenario, run.times[rid]).items():
            out[(rid, name)] = winding(path, centres)
        for name, centres in centroids.items():
            if name != run.formation_of[rid]:
                out[(rid, name)] = winding(path, centres)
    return out


def other_sides(a: dict[tuple[str, str], float],
                b: dict[tuple[str, str], float]) -> list[tuple[str, str]]:
    """The (robot, obstacle) pairs whose windings in ``a`` and ``b`` differ by pi or more: the
    robot passed that obstacle on the other side (or went round it a different number of
    times)."""
    return sorted(k for k in a if abs(a[k] - b[k]) >= math.pi)


@dataclass(frozen=True)
class Comparison:
    """One scenario in both engines."""

    name: str
    epsilon: float
    kinematic: Run
    mujoco: Run
    pairs: int  # (robot, obstacle) and (robot, other formation) pairs compared
    flipped: list[tuple[str, str]]  # those passed on the other side in MuJoCo

    @property
    def contacts(self) -> int:
        return int(self.mujoco.summary.get("physics", {}).get("collisions", -1))

    def eps(self, run: Run) -> float:
        return run.summary["formation_error_max_m"] / self.epsilon

    @property
    def holds(self) -> bool:
        """The bar in MuJoCo: 0 contacts, every goal, <= 1.5 eps, the same sides."""
        s = self.mujoco.summary
        return (self.contacts == 0 and bool(s["all_reached"]) and self.eps(self.mujoco) <= 1.5
                and not self.flipped)

    def row(self) -> str:
        k, m = self.kinematic.summary, self.mujoco.summary

        def when(s: dict) -> str:
            t = s.get("time_to_goal_s")
            return "-" if t is None else f"{t:.1f}"

        sides = "same" if not self.flipped else \
            f"{len(self.flipped)} flipped: " + ", ".join(f"{r}/{o}" for r, o in self.flipped[:4])
        return (f"| {self.name} | {_yes(k['all_reached'])} / {_yes(m['all_reached'])} | "
                f"{k['collisions']} / {m['collisions']} | {self.contacts} | "
                f"{self.eps(self.kinematic):.2f} / {self.eps(self.mujoco):.2f} | "
                f"{when(k)} / {when(m)} | {self.pairs}: {sides} | "
                f"{'pass' if self.holds else 'FAIL'} |")


HEADER = ("| scenario | every goal (kin. / MuJoCo) | collisions (kin. / MuJoCo) | MuJoCo contacts "
          "| worst error [eps] (kin. / MuJoCo) | time to goal [s] (kin. / MuJoCo) "
          "| sides: pairs compared, flipped | bar |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- |")


def _yes(b: bool) -> str:
    return "yes" if b else "no"


def compare(scenario: Scenario, kinematic: Path, mujoco: Path) -> Comparison:
    """Compare two finished runs of ``scenario`` (their ``--out`` folders)."""
    k, m = Run.read(kinematic), Run.read(mujoco)
    wk, wm = windings(scenario, k), windings(scenario, m)
    return Comparison(scenario.name, scenario.controller.epsilon, k, m, len(wk),
                      other_sides(wk, wm))


def run_both(path: Path, out: Path, realtime: bool = False) -> Comparison:
    """Run ``path`` in both engines into ``out/kinematic`` and ``out/mujoco`` and compare
    (each through the ``formation`` command line, in a process of its own)."""
    common = ["--quiet", "--no-plots", "--force"]
    for engine in ("kinematic", "mujoco"):
        mode = ["run", "--realtime", "--insecure"] if realtime and engine == "mujoco" else ["sim"]
        done = subprocess.run([sys.executable, "-m", "formation", mode[0], str(path), "--out",
                               str(out / engine), *common, *mode[1:], "--engine", engine],
                              capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"{path}: formation {mode[0]} --engine {engine} exited "
                               f"{done.returncode}: {done.stderr.strip()[-500:]}")
    return compare(load_scenario(path), out / "kinematic", out / "mujoco")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.engines", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenarios", nargs="+", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--realtime", action="store_true",
                   help="MuJoCo through `formation run --realtime` instead of `formation sim`")
    p.add_argument("--compare-only", action="store_true",
                   help="compare the runs already in --out instead of running them")
    a = p.parse_args(argv)
    rows = []
    for path in a.scenarios:
        out = a.out / path.stem
        c = (compare(load_scenario(path), out / "kinematic", out / "mujoco") if a.compare_only
             else run_both(path, out, a.realtime))
        rows.append(c)
        print(c.row(), file=sys.stderr, flush=True)  # progress, between the runs' own lines
    print(HEADER)
    print("\n".join(c.row() for c in rows))
    return 0 if all(c.holds for c in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

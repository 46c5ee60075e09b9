"""CPU time of the agents' real-time tick, in one process and without Zenoh, for A/B comparisons.

    PYTHONPATH=TREE python benchmarks/agent_tick.py [--robots 32] [--hz 50] [--seconds 10]
        [--slots 8] [--profile FILE] [--json FILE] [--opcodes]

The agents of :func:`experiments.fleet_scenario.fleet_scenario` (the fleet ``formation bench
--fleets`` runs) as real-time agent nodes ticking on pose arrival, as an agent host runs them, on
an in-memory session: a put reaches every matching subscriber at once (a callback is called, a
ring channel queues the sample), so only the agents' own work is measured, not Zenoh's. A small
world in this process moves each robot by its last command (single integrator) and publishes
the obstacles and every pose on a virtual clock (``time.time`` is replaced by it: stamps and
freshness as in real time, the machine's load does not make inputs stale). Each pose put is
timed with the thread's CPU clock: the pose callback and the tick it runs (drain, tick, puts).
The code under test is whatever ``PYTHONPATH`` points at, so two trees run the same script.

``--opcodes`` counts instead the Python bytecodes and calls each timed pose put runs
(``sys.settrace``): a measure of the interpreter's work that other jobs on the machine do not
move, for comparing trees on a busy machine (work done in C, such as a solver or the
serializer, is not in it). The tracing slows the wall clock, so the viewers' diagnostics,
paced by it, are left out in this mode.
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import gc
import json
import statistics
import sys
import time
from collections import deque
from typing import Any

import zenoh

from agent.config import build_agent_configs
from agent.node import AgentNode, NodeOptions
from experiments.fleet_scenario import fleet_scenario
from wire import keys
from wire.diag import DiagPublisher

try:
    from runtime.heap import freeze_startup
except ImportError:  # older trees keep it in wire
    from wire.heap import freeze_startup  # type: ignore[no-redef]
from wire.payloads import ObstacleMsg, Obstacles, Pose, decode_cmd, encode_zbytes

RING = 256  # samples a ring channel keeps (agent.inbox.RING_CAPACITY)
LATENCY = 0.0005  # [s] virtual time from a pose's stamp to its tick


class VirtualClock:
    """``time.time`` while the benchmark runs."""

    def __init__(self, start: float) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now


class GcTime:
    """The cyclic collector's time [ms] and collections per generation (a ``gc.callbacks``)."""

    def __init__(self) -> None:
        self.ms = 0.0
        self.counts = [0, 0, 0]
        self._t0 = 0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter_ns()
        else:
            self.ms += (time.perf_counter_ns() - self._t0) / 1e6
            self.counts[info["generation"]] += 1


class Sample:
    __slots__ = ("key_expr", "payload", "kind")

    def __init__(self, key: str, payload: Any) -> None:
        self.key_expr = key
        self.payload = payload
        self.kind = zenoh.SampleKind.PUT


class Ring:
    """A subscriber with a ring channel."""

    def __init__(self) -> None:
        self.queue: deque[Sample] = deque(maxlen=RING)

    def try_recv(self) -> Sample | None:
        return self.queue.popleft() if self.queue else None

    def undeclare(self) -> None:
        pass


class Handle:
    def undeclare(self) -> None:
        pass


class Bus:
    """Every subscriber of the process, by key expression."""

    def __init__(self) -> None:
        self.subs: list[tuple[zenoh.KeyExpr, Any]] = []
        self.routes: dict[str, list[Any]] = {}

    def add(self, key: str, deliver: Any) -> None:
        self.subs.append((zenoh.KeyExpr(key), deliver))
        self.routes.clear()

    def put(self, key: str, payload: Any) -> None:
        route = self.routes.get(key)
        if route is None:
            k = zenoh.KeyExpr(key)
            route = self.routes[key] = [d for e, d in self.subs if e.intersects(k)]
        for deliver in route:
            deliver(Sample(key, payload))


class Publisher:
    def __init__(self, bus: Bus, key: str) -> None:
        self.bus = bus
        self.key_expr = key
        self.matching_status = True

    def put(self, payload: Any) -> None:
        self.bus.put(self.key_expr, payload if isinstance(payload, zenoh.ZBytes)
                     else zenoh.ZBytes(payload))

    def undeclare(self) -> None:
        pass


class Liveliness:
    def declare_token(self, _key: str) -> Handle:
        return Handle()

    def declare_subscriber(self, _key: str, _handler: Any = None, history: bool = False) -> Handle:
        return Handle()


class Session:
    """What an agent node asks of a ``zenoh.Session``, in memory."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus

    def declare_publisher(self, key: str, **_kw: Any) -> Publisher:
        return Publisher(self.bus, str(key))

    def declare_subscriber(self, key: str, handler: Any = None, **_kw: Any) -> Any:
        if isinstance(handler, zenoh.handlers.Callback):
            self.bus.add(str(key), handler.callback)
            return Handle()
        if callable(handler):
            self.bus.add(str(key), handler)
            return Handle()
        ring = Ring()
        self.bus.add(str(key), ring.queue.append)
        return ring

    def declare_queryable(self, _key: str, _handler: Any = None, **_kw: Any) -> Handle:
        return Handle()

    def liveliness(self) -> Liveliness:
        return Liveliness()

    def zid(self) -> str:
        return "0"

    def close(self) -> None:
        pass


class MemoryNode(AgentNode):
    """An agent node on the in-memory session."""

    session: Any = None

    def open_session(self) -> Any:
        return self.session

    def _open_session(self) -> Any:  # the same, under its name in older trees
        return self.session


def open_nodes(configs: dict[str, Any], session: Session) -> list[Any]:
    """One real-time agent node per configuration, open on ``session``."""
    loop = asyncio.new_event_loop()
    MemoryNode.session = session
    nodes = []
    for cfg in configs.values():
        node = MemoryNode(cfg, NodeOptions(trace=False))
        node.open(loop)
        nodes.append(node)
    return nodes


class World:
    """The robots (single integrators moved by their last command), the obstacles, and the
    publishing of a frame: the obstacles, then each formation's poses in its slot."""

    def __init__(self, scenario: Any, configs: dict[str, Any], bus: Bus, slots: int) -> None:
        prefix = next(iter(configs.values())).prefix
        self.ids = list(configs)
        self.start = {r.id: tuple(r.start[:2]) for r in scenario.robots}
        self.pos = {rid: list(self.start[rid]) for rid in self.ids}
        self.cmds: dict[str, Any] = dict.fromkeys(self.ids)  # the last command's payload
        for rid in self.ids:
            bus.add(keys.cmd_key(prefix, rid), self._taker(rid))
        self.pose_pubs = {rid: Publisher(bus, keys.pose_key(prefix, rid)) for rid in self.ids}
        self.obs_pub = Publisher(bus, keys.obstacles_key(prefix))
        self.obstacles = tuple(ObstacleMsg(o.name, o.center[0], o.center[1], 0.0, 0.0,
                                           o.safe_distance) for o in scenario.obstacles)
        order = sorted({c.formation for c in configs.values()}, key=lambda f: int(f[1:]))
        self.slots = max(1, slots)
        slot_of = {f: i % self.slots for i, f in enumerate(order)}
        self.in_slot = [[rid for rid in self.ids if slot_of[configs[rid].formation] == k]
                        for k in range(self.slots)]

    def _taker(self, rid: str) -> Any:
        def take(sample: Sample) -> None:
            self.cmds[rid] = sample.payload  # decoded by the world, outside the timed put
        return take

    def poses(self, base: float, dt: float) -> list[tuple[str, float, Any]]:
        """Every robot moved by its last command over ``dt``: (robot, stamp, pose payload)."""
        out = []
        for slot, rids in enumerate(self.in_slot):
            stamp = base + slot * dt / self.slots
            for rid in rids:
                last = self.cmds[rid]
                c = None if last is None else decode_cmd(last.to_bytes())
                x, y = self.pos[rid]
                if c is not None:
                    x, y = x + c.ux * dt, y + c.uy * dt
                self.pos[rid] = [x, y]
                out.append((rid, stamp, encode_zbytes(Pose(x, y, 0.0, stamp))))
        return out


class OpCounter:
    """Bytecodes and calls run while enabled (a ``cProfile.Profile`` stand-in for :func:`drive`)."""

    def __init__(self) -> None:
        self.opcodes = 0
        self.calls = 0

    def _local(self, _frame: Any, event: str, _arg: Any) -> Any:
        if event == "opcode":
            self.opcodes += 1
        return self._local

    def _global(self, frame: Any, event: str, _arg: Any) -> Any:
        if event != "call":
            return None
        self.calls += 1
        frame.f_trace_opcodes = True
        return self._local

    def enable(self) -> None:
        sys.settrace(self._global)

    def disable(self) -> None:
        sys.settrace(None)


def drive(world: World, clock: VirtualClock, frames: int, dt: float, warm: int,
          prof: cProfile.Profile | OpCounter | None) -> list[int]:
    """Run ``frames`` frames; the CPU time [ns] of each pose put after the first ``warm``
    frames (profiled with ``prof``)."""
    cpu: list[int] = []
    t0 = clock.now
    for k in range(frames):
        base = t0 + k * dt
        clock.now = base
        world.obs_pub.put(encode_zbytes(Obstacles(base, world.obstacles)))
        timed = prof if k >= warm else None
        for rid, stamp, payload in world.poses(base, dt):
            clock.now = stamp + LATENCY
            if timed is not None:
                timed.enable()
            c0 = time.thread_time_ns()
            world.pose_pubs[rid].put(payload)
            c1 = time.thread_time_ns()
            if timed is not None:
                timed.disable()
            if k >= warm:
                cpu.append(c1 - c0)
    return cpu


def summary(stats: list[dict], cpu: list[int]) -> dict:
    """The figures of a run from the agents' counters and the timed puts."""
    us = [c / 1e3 for c in cpu]
    out = {
        "timed_ticks": len(us),
        "tick_cpu_us_median": statistics.median(us), "tick_cpu_us_mean": statistics.fmean(us),
        "tick_cpu_us_p90": sorted(us)[int(0.9 * (len(us) - 1))],
        "stale": sum(s["stale"] for s in stats),
        "stale_why": _sum(s["stale_why"] for s in stats),
        "solves": sum(s["solves"] for s in stats),
        "ticks": sum(s["ticks"] for s in stats),
        "tick_us_median_of_agents": statistics.median(
            s["tick_us_median"] for s in stats if s["tick_us_median"] is not None),
        "solve_us_median_of_agents": statistics.median(
            s["solve_us_median"] for s in stats if s["solve_us_median"] is not None),
    }
    parts = [s.get("tick_parts_us_median") for s in stats]
    if parts and all(parts):
        out["tick_parts_us_median"] = {
            p: statistics.median(x[p] for x in parts if x.get(p) is not None) for p in parts[0]}
    return out


def run(robots: int, hz: float, seconds: float, slots: int, profile: str | None,
        opcodes: bool = False) -> dict:
    dt = 1.0 / hz
    clock = VirtualClock(1.0e9)
    time.time = clock  # type: ignore[assignment]  # stamps and freshness on the virtual clock
    scenario = fleet_scenario(robots, dt, seconds)
    configs = build_agent_configs(scenario)
    bus = Bus()
    nodes = open_nodes(configs, Session(bus))
    world = World(scenario, configs, bus, slots)
    freeze_startup()  # as each node does once open
    gc_time = GcTime()
    gc.callbacks.append(gc_time)
    frames = int(round(seconds * hz))
    prof: cProfile.Profile | OpCounter | None = cProfile.Profile() if profile else None
    if opcodes:
        prof = OpCounter()
        # paced by the wall clock, which the tracing slows (module docstring)
        DiagPublisher.tick = lambda *_args: None  # type: ignore[method-assign]
    cpu = drive(world, clock, frames, dt, min(frames // 5, int(hz)), prof)
    gc.callbacks.remove(gc_time)
    stats = [n.stats() for n in nodes]
    for node in nodes:
        node.close()
    if isinstance(prof, cProfile.Profile) and profile:
        prof.dump_stats(profile)
    out = {"robots": robots, "hz": hz, "frames": frames,
           **summary([s if isinstance(s, dict) else s.to_json_dict() for s in stats], cpu),
           "gc_ms": gc_time.ms, "gc_collections": gc_time.counts,
           "distance_m": statistics.fmean(world.pos[r][0] - world.start[r][0]
                                          for r in world.ids)}
    if isinstance(prof, OpCounter):
        out["opcodes_per_put"] = prof.opcodes / len(cpu)
        out["calls_per_put"] = prof.calls / len(cpu)
    return out


def _sum(dicts: Any) -> dict[str, int]:
    total: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            total[k] = total.get(k, 0) + v
    return total


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=32)
    ap.add_argument("--hz", type=float, default=50.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--slots", type=int, default=8)
    ap.add_argument("--profile", default=None, help="write a cProfile of the timed pose puts")
    ap.add_argument("--json", default=None, help="write the figures to this file too")
    ap.add_argument("--opcodes", action="store_true",
                    help="count the bytecodes and calls of each timed pose put instead")
    ns = ap.parse_args(argv)
    out = run(ns.robots, ns.hz, ns.seconds, ns.slots, ns.profile, ns.opcodes)
    text = json.dumps(out, indent=2)
    print(text)
    if ns.json:
        with open(ns.json, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

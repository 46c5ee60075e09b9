"""SIGTERM and SIGINT under a flood of messages, over real Zenoh: every agent sends zero and
writes its counters (issue 13: under load asyncio's signal wakeup fd overflowed, the signal was
lost, the launcher SIGKILLed the agent: no zero command, no counters)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, save_config
from leader.ellipse import Ellipse
from leader.role import ellipse_to_msg
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from wire import keys, zconf
from wire.payloads import Cmd, ObstacleMsg, Obstacles, Others, Pose, State, decode_cmd, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "thesis-5.2.2.yaml"
TIMEOUT_S = 15.0
MALFORMED_PER_VALID = 10  # during the flood (~200 valid sends a second per key)
# members r1 and r4 of F1, twice: in lock-step under prefix "ls", in real time under "rt"
AGENTS = {("ls", "r1"): ("--lockstep",), ("ls", "r4"): ("--lockstep",),
          ("rt", "r1"): (), ("rt", "r4"): ()}


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc


class Flood:
    """Publishes, from a thread, every 2 ms, everything the agents read: their poses, their
    neighbours' states, their leader's ``others`` and the obstacles (valid: they tick and
    command); once ``flooding`` is set, each is followed by MALFORMED_PER_VALID malformed
    payloads on the same key (about 50,000 messages a second in all). Lock-step stamps are the
    first frame's (0.0: the agents tick once, then every message only wakes their loop), real
    time's are now."""

    def __init__(self, session: zenoh.Session, starts: dict[str, tuple[float, float]]) -> None:
        self.starts = starts
        self.pubs: dict[tuple[str, str], zenoh.Publisher] = {}
        for prefix in ("ls", "rt"):
            for k in (keys.obstacles_key(prefix), keys.others_key(prefix, "F1"),
                      *(keys.pose_key(prefix, r) for r in ("r1", "r4")),
                      *(keys.state_key(prefix, r) for r in ("r1", "r2", "r3", "r4"))):
                self.pubs[(prefix, k)] = session.declare_publisher(k)
        self.sent = 0
        self.flooding = threading.Event()  # set: malformed payloads between the valid ones
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10.0)

    def payload(self, prefix: str, key: str, stamp: float) -> bytes:
        cls = keys.key_class(prefix, key)
        rid = key.split("/")[-2]
        if cls == keys.POSE:
            return encode(Pose(*self.starts[rid], 0.0, stamp))
        if cls == keys.STATE:
            return encode(State(*self.starts[rid], 0.2, 0.0, stamp))  # driving to +x
        if cls == keys.OTHERS:
            own = ellipse_to_msg("F1", Ellipse(-3.0, 0.0, 0.0, 0.6, 0.3), stamp)
            other = ellipse_to_msg("F2", Ellipse(3.0, 0.3, 0.0, 0.6, 0.3), stamp)
            return encode(Others("F1", stamp, (other,), own))
        return encode(Obstacles(stamp, (ObstacleMsg("o1", 9.0, 9.0, 0.0, 0.0, 0.3),)))

    def _run(self) -> None:
        k = 0
        while not self._stop.is_set():
            now = time.time()
            for (prefix, key), pub in self.pubs.items():
                pub.put(self.payload(prefix, key, 0.0 if prefix == "ls" else now))
                self.sent += 1
                if self.flooding.is_set():
                    for _ in range(MALFORMED_PER_VALID):
                        pub.put(b"\x07" + bytes(k % 50))
                        k += 1
                    self.sent += MALFORMED_PER_VALID
            time.sleep(0.002)


def _start_agents(configs: dict, stats: dict, logs: dict, tmp_path, procs: dict) -> None:
    """Every agent of AGENTS as a process of its own, each with its extra options, into
    ``procs`` as it starts (so that a failure half way still reaps those started)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for (prefix, rid), extra in AGENTS.items():
        path = tmp_path / f"{prefix}-{rid}.yaml"
        save_config(configs[prefix][rid], path)
        procs[(prefix, rid)] = subprocess.Popen(
            [sys.executable, "-m", "agent", "--config", str(path),
             "--stats", str(stats[(prefix, rid)]), "--no-trace", *extra],
            env=env, stdin=subprocess.DEVNULL, stderr=logs[(prefix, rid)],
            start_new_session=True)


def _signal_under_the_flood(flood: Flood, procs: dict, moving, cmds: dict) -> dict:
    """Once every agent commands motion, flood for a while and stop the agents, half with
    SIGTERM and half with SIGINT, while the flood goes on; their exit codes."""
    for (_prefix, key), pub in flood.pubs.items():
        if key.endswith("/pose"):
            wait_for_matching(pub, TIMEOUT_S)
    flood.start()
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not all(moving(a) for a in AGENTS):  # every agent commands motion
            assert time.monotonic() < deadline, {a: cmds[a][-2:] for a in AGENTS if not moving(a)}
            time.sleep(0.05)
        flood.flooding.set()
        time.sleep(1.5)
        for k, p in enumerate(procs.values()):  # stop them while the flood goes on
            p.send_signal(signal.SIGTERM if k % 2 == 0 else signal.SIGINT)
        return {a: p.wait(TIMEOUT_S) for a, p in procs.items()}
    finally:
        flood.stop()


def _reap(procs: dict, logs: dict) -> None:
    for p in procs.values():
        if p.poll() is None:
            p.kill()
            p.wait()
    for f in logs.values():
        f.close()


def _ends_in_zero(cmds, agent, lock) -> bool:
    with lock:
        got = cmds[agent]
        return bool(got) and (got[-1].v, got[-1].omega, got[-1].ux, got[-1].uy) == (0.0,) * 4


def test_sigterm_and_sigint_under_a_flood_end_in_zero_and_counters_for_every_agent(
        router, tmp_path):
    scenario = load_scenario(SCENARIO)
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    configs = {prefix: build_agent_configs(scenario, prefix=prefix, zenoh=zs)
               for prefix in ("ls", "rt")}
    starts = {r.id: r.start[:2] for r in scenario.robots}
    conf = zconf.make_config("client", connect=[router.endpoint], connect_timeout_s=TIMEOUT_S)
    lock = threading.Lock()
    cmds: dict[tuple[str, str], list[Cmd]] = {a: [] for a in AGENTS}

    def on_cmd(sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        with lock:
            cmds[(parts[0], parts[-2])].append(decode_cmd(sample.payload.to_bytes()))

    def moving(agent: tuple[str, str]) -> bool:
        with lock:
            return any(math.hypot(c.ux, c.uy) > 0.05 for c in cmds[agent])

    procs: dict[tuple[str, str], subprocess.Popen] = {}
    stats = {a: tmp_path / f"{a[0]}-{a[1]}.json" for a in AGENTS}
    logs = {a: (tmp_path / f"{a[0]}-{a[1]}.log").open("wb") for a in AGENTS}
    with zenoh.open(conf) as session:
        subs = [session.declare_subscriber(keys.all_robots_key(prefix, keys.CMD), on_cmd)
                for prefix in ("ls", "rt")]
        try:
            _start_agents(configs, stats, logs, tmp_path, procs)
            flood = Flood(session, starts)
            codes = _signal_under_the_flood(flood, procs, moving, cmds)
            # the last commands cross the router: wait until each agent's latest is the zero
            # (a non-zero command put after it would stay the latest and fail below)
            deadline = time.monotonic() + 15.0
            while time.monotonic() < deadline and not all(_ends_in_zero(cmds, a, lock)
                                                          for a in AGENTS):
                time.sleep(0.05)
            assert flood.sent > 10_000
        finally:
            for sub in subs:
                sub.undeclare()
            _reap(procs, logs)
    errors = {a: (tmp_path / f"{a[0]}-{a[1]}.log").read_text(errors="replace") for a in AGENTS}
    assert codes == dict.fromkeys(AGENTS, 0), errors
    for a in AGENTS:
        last = cmds[a][-1]
        assert (last.v, last.omega, last.ux, last.uy) == (0.0, 0.0, 0.0, 0.0), a
        counters = json.loads(stats[a].read_text())
        assert counters["ticks"] > 0 and sum(counters["dropped"].values()) > 0, a
        assert "wakeup fd" not in errors[a], errors[a]

"""Hostile bytes on every key the runtime subscribes to, over real Zenoh sessions on loopback.

Two agent processes (r1, a member that also runs with message loss, so the fault path sees the
garbage too; r2, its leader) and the simulated world (in this process) subscribe through a Python
router; a fuzzer session publishes seeded random, truncated, corrupted, non-finite and oversized
payloads on each of those keys: ``pose``, ``state``, ``ellipse``, ``others``, ``obstacles`` (the
agents) and ``cmd`` (the world). Nothing may crash; every payload must be dropped and counted.
"""

from __future__ import annotations

import json
import os
import random
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, save_config
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from simulator.world import World, WorldOptions
from wire import keys, zconf
from wire.payloads import (
    MAX_PAYLOAD_BYTES,
    Cmd,
    DecodeError,
    EllipseMsg,
    ObstacleMsg,
    Obstacles,
    Others,
    Pose,
    State,
    decode_cmd,
    decode_ellipse,
    decode_obstacles,
    decode_others,
    decode_pose,
    decode_state,
    encode,
)

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "thesis-5.2.2.yaml"
P = keys.DEFAULT_PREFIX
PER_KEY = 200  # hostile payloads per key
TIMEOUT_S = 15.0

_E = EllipseMsg("F2", 0.0, 0.0, 0.1, 0.6, 0.3, 0.1, 0.0, 0.0, 1.0)
VALID: dict[str, tuple[bytes, Callable[[bytes], object]]] = {
    keys.POSE: (encode(Pose(1.0, 2.0, 0.3, 1.0)), decode_pose),
    keys.STATE: (encode(State(1.0, 2.0, 0.1, 0.0, 1.0)), decode_state),
    keys.CMD: (encode(Cmd(0.1, 0.2, 0.1, 0.0, 1.0)), decode_cmd),
    keys.ELLIPSE: (encode(_E), decode_ellipse),
    keys.BEACON: (encode(_E), decode_ellipse),
    keys.OTHERS: (encode(Others("F1", 1.0, (_E,), None)), decode_others),
    keys.OBSTACLES: (encode(Obstacles(1.0, (ObstacleMsg("o1", 1.0, 1.0, 0.0, 0.0, 0.3),))),
                     decode_obstacles),
}


def hostile(cls: str, rng: random.Random, n: int) -> list[bytes]:
    """``n`` payloads that the ``cls`` decoder rejects: random, truncated, corrupted, wrong
    version, trailing bytes, non-finite, over-long varints, oversized."""
    valid, decode = VALID[cls]
    out: list[bytes] = []
    makers: list[Callable[[], bytes]] = [
        lambda: rng.randbytes(rng.randint(0, 120)),
        lambda: valid[: rng.randint(0, len(valid) - 1)],
        lambda: valid + rng.randbytes(rng.randint(1, 9)),
        lambda: bytes([rng.choice([0, 2, 255])]) + valid[1:],
        lambda: valid[:1] + struct.pack("<d", rng.choice([float("nan"), float("inf")])) + valid[9:],
        lambda: valid[:1] + b"\xff" * rng.randint(1, 12) + valid[1:],  # varint-ish garbage
        lambda: bytes(b ^ (1 << rng.randrange(8)) if rng.random() < 0.2 else b for b in valid),
    ]
    out.append(valid[:1] + rng.randbytes(MAX_PAYLOAD_BYTES + rng.randint(1, 64)))  # oversized
    while len(out) < n:
        data = makers[len(out) % len(makers)]()
        try:
            decode(data)
        except DecodeError:
            out.append(data)
    return out


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc


def _start_agent(cfg_path: Path, stats: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p))
    return subprocess.Popen([sys.executable, "-m", "agent", "--config", str(cfg_path),
                             "--stats", str(stats), *extra], env=env, stdin=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)


def test_hostile_payloads_on_every_subscribed_key_are_dropped_and_counted_never_fatal(
        router, tmp_path):
    scenario = load_scenario(SCENARIO)
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    configs = build_agent_configs(scenario, zenoh=zs)
    procs: dict[str, subprocess.Popen] = {}
    try:
        for rid, extra in (("r1", ("--drop", "0.2")), ("r2", ())):
            save_config(configs[rid], tmp_path / f"{rid}.yaml")
            procs[rid] = _start_agent(tmp_path / f"{rid}.yaml", tmp_path / f"{rid}.json", *extra)
        conf = zconf.make_config("client", connect=[router.endpoint], connect_timeout_s=TIMEOUT_S)
        with zenoh.open(conf) as session:
            world = World(scenario, session, WorldOptions())
            try:
                pubs, sent = _fuzz(session)
                _check_alive_and_counting(world, procs)
                time.sleep(2.0)  # the agents' queues drain too (they get SIGTERM next)
                for pub in pubs.values():
                    pub.undeclare()
            finally:
                world.close()
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        for rid, p in procs.items():
            _, err = p.communicate(timeout=TIMEOUT_S)
            assert p.returncode == 0, (rid, err.decode(errors="replace"))
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()

    _check_counters(tmp_path, sent)


def _fuzz(session: zenoh.Session) -> tuple[dict, dict[str, int]]:
    """Hostile payloads on every key r1, r2 and the world subscribe to; the publishers and how
    many went out per key."""
    targets = {  # key -> class: what r1, r2 and the world subscribe to
        keys.pose_key(P, "r1"): keys.POSE, keys.pose_key(P, "r2"): keys.POSE,
        keys.state_key(P, "r1"): keys.STATE, keys.state_key(P, "r2"): keys.STATE,
        keys.state_key(P, "r3"): keys.STATE, keys.state_key(P, "r4"): keys.STATE,
        # r2 leads F1: in real time it hears F2's ellipse only once a valid beacon
        # says F2 is near (leader.listen); the beacon, the same EllipseMsg, comes
        # through a wildcard
        keys.beacon_key(P, "F2"): keys.BEACON,
        keys.others_key(P, "F1"): keys.OTHERS,
        keys.obstacles_key(P): keys.OBSTACLES,
        keys.cmd_key(P, "s1"): keys.CMD, keys.cmd_key(P, "s3"): keys.CMD,
    }
    pubs = {k: session.declare_publisher(
        k, congestion_control=zenoh.CongestionControl.BLOCK) for k in targets}
    for k, pub in pubs.items():
        if keys.key_class(P, k) != keys.CMD:
            wait_for_matching(pub, TIMEOUT_S)  # the agents have subscribed
    rng = random.Random(20240611)
    sent: dict[str, int] = {}
    for k, cls in targets.items():
        for data in hostile(cls, rng, PER_KEY):
            pubs[k].put(data)
            sent[k] = sent.get(k, 0) + 1
            time.sleep(0.001)  # the router drops on congestion; stay well below it
    return pubs, sent


def _check_alive_and_counting(world: World, procs: dict[str, subprocess.Popen]) -> None:
    """After the fuzz: both agents still alive and commanding (zero: no valid pose ever came),
    and the world counted the malformed commands it was sent."""
    t_fuzz = time.monotonic()
    deadline = t_fuzz + TIMEOUT_S
    while time.monotonic() < deadline:
        latest = dict(world.inbox.latest)
        if all(r in latest and latest[r][1] > t_fuzz for r in ("r1", "r2")):
            break
        time.sleep(0.05)
    assert all(p.poll() is None for p in procs.values())
    assert all(latest[r][1] > t_fuzz and latest[r][0].v == 0.0 for r in ("r1", "r2"))
    deadline = time.monotonic() + TIMEOUT_S
    while world.inbox.malformed < 2 * PER_KEY and time.monotonic() < deadline:
        time.sleep(0.05)
    assert 0.9 * 2 * PER_KEY <= world.inbox.malformed <= 2 * PER_KEY


def _check_counters(tmp_path: Path, sent: dict[str, int]) -> None:
    """Each agent's counters: every payload that reached it dropped as malformed."""
    def expected(rid: str) -> dict[str, int]:
        subs = set(json.loads((tmp_path / f"{rid}.json").read_text())["subscriptions"])
        out: dict[str, int] = {}
        for k, n in sent.items():
            if any(zenoh.KeyExpr(sub).intersects(zenoh.KeyExpr(k)) for sub in subs):
                out[keys.key_class(P, k)] = out.get(keys.key_class(P, k), 0) + n
        return out

    for rid in ("r1", "r2"):
        stats = json.loads((tmp_path / f"{rid}.json").read_text())
        want = expected(rid)
        assert set(want) == set(stats["dropped"]), rid  # every class it subscribes to was hit
        # every payload that arrived was dropped as malformed (none accepted, nothing else came);
        # Zenoh itself may lose a few under congestion, so arrivals are at most what was sent
        assert stats["dropped"] == stats["received"], rid
        for cls, n in want.items():
            assert 0.9 * n <= stats["received"][cls] <= n, (rid, cls)
        assert sum(stats["fault_dropped"].values()) == 0  # garbage is malformed, not "lost"
        assert stats["solves"] == 0 and stats["waiting"] > 0

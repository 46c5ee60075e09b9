"""Old, future, forged and malformed inputs fed into whole runs over real Zenoh (issues 13, 14).

An attacker session connects to the run's own router (``formation run --port``) and publishes on
the keys the agents and the world subscribe to while the run goes on:

* lock-step: poses and commands stamped in the future and a flood of malformed payloads on every
  key. Nothing may stall or desynchronise the run: ``robots.csv`` is byte-identical to the
  in-process simulation's (which equals a clean ``formation run``'s: tests/test_launch.py), and
  every refused message is counted.
* real time: each robot's own poses re-published 2 s later, poses at (1e9, 1e9), neighbour states
  with ux = 1e6 and empty obstacle lists, all stamped now: no collision, each kind refused and
  counted by the agents.
"""

from __future__ import annotations

import json
import random
import threading
import time
from collections import deque
from pathlib import Path

import pytest
import zenoh

from formation.cli import main
from runtime.testing import free_tcp_port, tcp_endpoint
from scenario import load_scenario
from wire import keys, zconf
from wire.payloads import Cmd, Obstacles, Pose, State, decode_pose, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
TWO = ROOT / "tests" / "scenarios" / "two-small.yaml"
P = keys.DEFAULT_PREFIX


class Attacker:
    """A session on the run's router, publishing from a thread until :meth:`stop`."""

    def __init__(self, port: int, robots: list[str], formations: list[str]) -> None:
        self.port = port
        self.robots = robots
        self.formations = formations
        self.sent: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.error: BaseException | None = None

    def __enter__(self) -> Attacker:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(10.0)

    def _session(self) -> zenoh.Session | None:
        conf = zconf.make_config("client", connect=[tcp_endpoint(self.port)],
                                 connect_timeout_s=1.0)
        while not self._stop.is_set():
            try:
                return zenoh.open(conf)
            except Exception:  # noqa: BLE001 - the router is not up yet
                time.sleep(0.05)
        return None

    def _run(self) -> None:
        try:
            session = self._session()
            if session is None:
                return
            with session:
                self.attack(session)
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    def put(self, pubs: dict, key: str, payload: bytes, kind: str) -> None:
        pubs[key].put(payload)
        self.sent[kind] = self.sent.get(kind, 0) + 1

    def attack(self, session: zenoh.Session) -> None:
        raise NotImplementedError


class LockstepAttacker(Attacker):
    """Future-stamped poses and commands, plus malformed payloads on every key, ~1,000/s."""

    def attack(self, session: zenoh.Session) -> None:
        rng = random.Random(14)
        targets = [keys.obstacles_key(P)]
        for r in self.robots:
            targets += [keys.pose_key(P, r), keys.state_key(P, r), keys.cmd_key(P, r)]
        for f in self.formations:
            targets += [keys.ellipse_key(P, f), keys.others_key(P, f)]
        pubs = {k: session.declare_publisher(k) for k in targets}
        n = 0
        while not self._stop.is_set():
            for r in self.robots:  # future stamps: far off, and inside the run's duration
                for stamp in (1e6, 30.0):
                    self.put(pubs, keys.pose_key(P, r), encode(Pose(0.0, 0.0, 0.0, stamp)),
                             "future_pose")
                    self.put(pubs, keys.cmd_key(P, r), encode(Cmd(0.2, 0.0, 0.2, 0.0, stamp)),
                             "future_cmd")
            for _ in range(20):
                key = targets[n % len(targets)]
                n += 1
                self.put(pubs, key, rng.randbytes(rng.randint(0, 60)), "malformed")
            time.sleep(0.02)


def _csv(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def test_future_stamps_and_a_malformed_flood_leave_lock_step_identical_to_the_simulation(
        tmp_path):
    sc = load_scenario(TWO)
    assert main(["sim", str(TWO), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    port = free_tcp_port()
    with LockstepAttacker(port, list(sc.robot_ids), [f.name for f in sc.formations]) as attacker:
        # access control off (--insecure): the attacker publishes as anyone could on an open router
        assert main(["run", str(TWO), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                     "--insecure", "--port", str(port)]) == 0
    assert attacker.error is None
    assert attacker.sent["malformed"] > 500 and attacker.sent["future_pose"] > 100
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert _csv(tmp_path / "run" / "robots.csv") == _csv(tmp_path / "sim" / "robots.csv")
    assert run["all_reached"] and run["collisions"] == 0
    agents, world = run["agents"], run["world"]
    assert agents["stamp_rejected"]["pose"]["future"] > 0
    assert world["stamp_rejected"]["cmd"]["future"] > 0
    assert sum(agents["dropped"].values()) > 0 and world["malformed_cmds"] > 0
    assert agents["stale"] == 0 and world["missing_cmds"] == 0


class RealtimeAttacker(Attacker):
    """Once every robot's poses flow: each robot's own poses re-published 2 s later and empty
    obstacle lists stamped 20 ms ahead, every 50 ms; for the first :data:`FORGE_S` also poses at
    (1e9, 1e9) and states with ux = 1e6 stamped now (each makes its receivers stop for a tick:
    forged without end, they would keep the robots standing, which is safe but tests nothing
    else)."""

    REPLAY_S = 2.0
    FORGE_S = 1.0

    def wait_for_commands(self, session: zenoh.Session) -> None:
        """Until every robot has commanded once (or the attack is stopped)."""
        lock = threading.Lock()
        commanding: set[str] = set()

        def on_cmd(sample: zenoh.Sample) -> None:
            with lock:
                commanding.add(str(sample.key_expr).split("/")[-2])

        cmd_sub = session.declare_subscriber(keys.all_robots_key(P, keys.CMD), on_cmd)
        while not self._stop.is_set():
            with lock:
                if commanding.issuperset(self.robots):
                    break
            time.sleep(0.02)
        cmd_sub.undeclare()

    def replay_and_forge(self, pubs: dict, r: str, seen: tuple, forge: bool) -> None:
        """Robot ``r``'s genuine poses older than REPLAY_S put again, and while ``forge`` a pose
        far away and a state at an impossible speed; ``seen``: the lock, the genuine poses'
        history and the latest genuine pose per robot."""
        lock, history, latest = seen
        now, mono = time.time(), time.monotonic()
        with lock:
            due = []
            while history[r] and history[r][0][0] <= mono - self.REPLAY_S:
                due.append(history[r].popleft()[1])
            last = latest[r]
        for data in due:
            self.put(pubs, keys.pose_key(P, r), data, "old_pose")
        if forge:
            self.put(pubs, keys.pose_key(P, r), encode(Pose(1e9, 1e9, 0.0, now)), "forged_pose")
            self.put(pubs, keys.state_key(P, r), encode(State(last.x, last.y, 1e6, 0.0, now)),
                     "forged_state")

    def attack(self, session: zenoh.Session) -> None:
        lock = threading.Lock()
        history: dict[str, deque[tuple[float, bytes]]] = {r: deque() for r in self.robots}
        latest: dict[str, Pose] = {}

        def on_pose(sample: zenoh.Sample) -> None:
            rid = str(sample.key_expr).split("/")[-2]
            data = sample.payload.to_bytes()
            try:
                pose = decode_pose(data)
            except ValueError:
                return
            if rid in history and abs(pose.x) < 1e3 and pose.stamp > time.time() - 0.5:
                with lock:  # a genuine pose (not one of ours): keep it for the replay
                    history[rid].append((time.monotonic(), data))
                    latest[rid] = pose

        # first wait for every agent's commands: a pose subscriber of ours before the agents'
        # would satisfy the world's wait for them (it waits for a match on each pose key)
        self.wait_for_commands(session)
        sub = session.declare_subscriber(keys.all_robots_key(P, keys.POSE), on_pose)
        pubs = {keys.obstacles_key(P): session.declare_publisher(keys.obstacles_key(P))}
        for r in self.robots:
            for k in (keys.pose_key(P, r), keys.state_key(P, r)):
                pubs[k] = session.declare_publisher(k)
        while not self._stop.is_set() and len(latest) < len(self.robots):
            time.sleep(0.02)
        time.sleep(0.5)  # the agents have their first genuine poses
        forge_until = time.monotonic() + self.FORGE_S
        while not self._stop.is_set():
            forge = time.monotonic() < forge_until
            for r in self.robots:
                self.replay_and_forge(pubs, r, (lock, history, latest), forge)
            # 20 ms ahead (inside the clock tolerance): newer than the world's next list, which
            # then comes stamped before the one kept and disagrees with it (a second source)
            self.put(pubs, keys.obstacles_key(P), encode(Obstacles(time.time() + 0.02, ())),
                     "empty_obstacles")
            time.sleep(0.05)
        sub.undeclare()


def test_old_forged_and_implausible_inputs_in_real_time_are_refused_counted_and_harmless(
        tmp_path):
    scenario = tmp_path / "near.yaml"
    # B passes the obstacle: driving straight (forgetting it) would take B 5 cm into it
    scenario.write_text(TWO.read_text(encoding="utf-8").replace("duration: 40.0", "duration: 6.0")
                        .replace("center: [1.0, -1.0]", "center: [1.4, -0.5]"), encoding="utf-8")
    sc = load_scenario(scenario)
    port = free_tcp_port()
    with RealtimeAttacker(port, list(sc.robot_ids), [f.name for f in sc.formations]) as attacker:
        assert main(["run", str(scenario), "--out", str(tmp_path / "run"), "--quiet",
                     "--no-plots", "--realtime", "--insecure", "--port", str(port)]) == 0
    assert attacker.error is None
    assert min(attacker.sent.get(k, 0) for k in ("old_pose", "forged_pose", "forged_state",
                                                 "empty_obstacles")) > 10
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["collisions"] == 0, run["collision_log"]
    agents = run["agents"]
    assert agents["stamp_rejected"]["pose"]["stale"] > 0  # the 2 s old replays
    assert agents["implausible"]["pose"] > 0  # (1e9, 1e9)
    assert agents["implausible"]["state"] > 0  # ux = 1e6
    # the empty lists stamped ahead, between the world's: a second source on the list, counted;
    # the robots avoid what both report (counted as held) rather than stop; an empty list taken
    # meanwhile (no world list stamped before it came after it) leaves its obstacles held
    assert agents["implausible"]["obstacles"] > 0 and agents["obstacle_held_ticks"] > 0
    assert agents["stale_why"].get("contested", 0) == 0
    assert agents["stale_why"]["implausible"] > 0  # ... each answered by a zero command
    # each agent counted what reached it: a member hears its neighbours' forged states
    per = {s: json.loads((tmp_path / "run" / "agents" / f"{s}.json").read_text())
           for s in sc.robot_ids}
    assert all(p["implausible"].get("pose", 0) > 0 for p in per.values())
    assert all(p["implausible"].get("state", 0) > 0 for p in per.values())


@pytest.mark.parametrize("offset_ms, reason", [(60, None), (250, "future")])
def test_a_camera_clock_off_by_more_than_the_window_stops_the_robots_and_is_counted(
        tmp_path, offset_ms, reason):
    # the world stamps poses on a camera clock offset_ms ahead of the agents' (chrony keeps real
    # ones within a few ms): inside the window (0.1 s ahead, stale_after less latency behind)
    # the run goes on; beyond it every pose is refused, counted, and no robot moves
    scenario = tmp_path / "short.yaml"
    scenario.write_text(TWO.read_text(encoding="utf-8").replace("duration: 40.0", "duration: 2.0"),
                        encoding="utf-8")
    assert main(["run", str(scenario), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                 "--realtime", "--clock-offset-ms", str(offset_ms)]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["world"]["clock_offset_s"] == offset_ms / 1000.0 and run["collisions"] == 0
    rejected = run["agents"]["stamp_rejected"].get("pose", {})
    if reason is None:
        assert not rejected and run["qp"]["solves"] > 100
    else:
        assert rejected[reason] > 50 and run["qp"]["solves"] == 0
        assert run["agents"]["waiting_for_pose"] > 20  # zero commands, counted


def test_a_clock_offset_needs_real_time(tmp_path):
    assert main(["run", str(TWO), "--out", str(tmp_path / "o"), "--clock-offset-ms", "50"]) == 2

"""Pose zones (:mod:`simulator.zones`): the world's poses and the agents' commands through zone
routers of the world's process instead of the run's router. Real Zenoh on loopback: a router,
the zone routers, one client session per robot connected to its zone's router, answering each
pose with a command as an agent does; and real ``formation run --pose-zones`` runs."""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
import threading
import time
from pathlib import Path

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments.fleet_scenario import fleet_scenario
from formation.cli import main
from runtime.testing import free_tcp_port
from simulator.world import World, WorldOptions
from simulator.zones import PoseZones, ZoneSecurity, zone_assignment
from wire import acl, keys, zconf
from wire.payloads import Cmd, decode_pose, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
TWO = ROOT / "tests" / "scenarios" / "two-small.yaml"
P = keys.DEFAULT_PREFIX


@settings(max_examples=30, deadline=None)
@given(formations=st.integers(1, 12), zones=st.integers(1, 16), hosts=st.sampled_from([1, 3, 4, 8]))
def test_zones_keep_each_formation_or_host_together_and_split_the_units_evenly(
        formations: int, zones: int, hosts: int) -> None:
    scenario = fleet_scenario(4 * formations, 0.05, 1.0)
    zone_of = zone_assignment(scenario, zones, hosts)
    assert set(zone_of) == set(scenario.robot_ids)
    ids = scenario.robot_ids
    units = ([[r.id for r in f.robots] for f in scenario.formations] if hosts == 1
             else [ids[i:i + hosts] for i in range(0, len(ids), hosts)])
    for unit in units:  # a formation (or a host's robots) never spans two zones
        assert len({zone_of[r] for r in unit}) == 1
    used = sorted(set(zone_of.values()))
    assert used == list(range(min(zones, len(units))))  # every zone serves someone
    sizes = [sum(1 for u in units if zone_of[u[0]] == z) for z in used]
    assert max(sizes) - min(sizes) <= 1


@pytest.mark.parametrize("bad", [0, -1, True, 1.5])
def test_a_zone_count_below_one_is_refused(bad) -> None:
    with pytest.raises(ValueError, match="pose zones"):
        zone_assignment(fleet_scenario(8, 0.05, 1.0), bad)


def test_every_pose_reaches_its_own_agent_and_every_command_the_world_through_zone_routers() -> None:
    steps = 15
    scenario = fleet_scenario(12, 0.05, 1.0)  # three four-robot formations
    scenario = dataclasses.replace(scenario, duration=steps * scenario.dt)
    ids = scenario.robot_ids
    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    got: dict[str, list[tuple[str, float, float, float]]] = {rid: [] for rid in ids}
    seen_by_viewer: list[str] = []
    lock = threading.Lock()
    router = zenoh.open(zconf.make_config("router", listen=[endpoint], scouting_delay_s=0.0))
    clients: list[zenoh.Session] = []
    try:
        with PoseZones(scenario, 3, endpoint) as zones:
            assert len(zones.sessions) == 3
            for rid in ids:  # an agent: its own pose in, a command stamped like it out
                s = zenoh.open(zconf.make_config("client", connect=[zones.endpoint_of(rid)]))
                clients.append(s)
                pub = s.declare_publisher(keys.cmd_key(P, rid))

                def on_pose(sample: zenoh.Sample, rid: str = rid, pub=pub) -> None:
                    p = decode_pose(sample.payload.to_bytes())
                    with lock:
                        got[rid].append((str(sample.key_expr), p.x, p.y, p.stamp))
                    pub.put(encode(Cmd(0.1, 0.0, 0.1, 0.0, p.stamp)))

                s.declare_subscriber(keys.pose_key(P, rid), on_pose)
            viewer = zenoh.open(zconf.make_config("client", connect=[endpoint]))
            clients.append(viewer)
            viewer.declare_subscriber(keys.all_robots_key(P, keys.POSE),
                                      lambda sample: seen_by_viewer.append(str(sample.key_expr)))
            world_session = zenoh.open(zconf.make_config("client", connect=[endpoint]))
            clients.append(world_session)
            world = World(scenario, world_session, WorldOptions(cmd_timeout=3.0, stop_at_goal=False,
                                                                start_grace=1.0),
                          zones.sessions, zones.zone_of)
            try:
                world.wait_for_agents()
                result = world.run()
            finally:
                world.close()
    finally:
        for s in clients:
            s.close()
        router.close()
    assert result.steps == steps
    assert result.cmd_timeouts == 0 and result.missing_cmds == 0  # every command came back
    assert result.stamp_rejected == {}  # and each came once (no copy through another zone)
    rows = {}
    for t, rid, *_rest in result.series.robots:
        rows.setdefault(rid, []).append((t, _rest[1], _rest[2]))  # t, x, y of the true pose
    for rid in ids:
        mine = got[rid]
        assert len(mine) == steps, (rid, len(mine))
        assert all(key == keys.pose_key(P, rid) for key, *_ in mine)
        # the poses this agent got are its own robot's, tick by tick
        for (_key, x, y, stamp), (t, tx, ty) in zip(mine, rows[rid], strict=True):
            assert stamp == pytest.approx(t)
            assert (x, y) == pytest.approx((tx, ty))
    # a subscriber on the run's router still sees every pose (zones are linked to it)
    assert sorted(seen_by_viewer) == sorted(keys.pose_key(P, r) for r in ids for _ in range(steps))


def run_cli(args: list[str]) -> int:
    return main(args)


def test_a_secure_lockstep_run_through_pose_zones_reaches_every_goal_byte_for_byte_as_the_simulation(
        tmp_path) -> None:
    assert run_cli(["sim", str(TWO), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert run_cli(["run", str(TWO), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                    "--pose-zones", "2"]) == 0  # secure by default: the zones hold the ACL
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["pose_zones"] == 2 and run["secure"]
    assert run["world"]["missing_cmds"] == 0 and run["agents"]["stale"] == 0
    configs = sorted((tmp_path / "run" / "configs").glob("*.yaml"))
    endpoints = {c.name: [ln for ln in c.read_text().splitlines() if "tcp/" in ln] for c in configs}
    assert len({tuple(e) for e in endpoints.values()}) == 2  # two formations, two zone routers
    assert (tmp_path / "run" / "robots.csv").read_text() == (tmp_path / "sim" / "robots.csv").read_text()


def test_a_realtime_run_of_agent_hosts_through_pose_zones_reaches_every_goal(tmp_path) -> None:
    assert run_cli(["run", str(TWO), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                    "--insecure", "--realtime", "--pose-zones", "2",
                    "--agents-per-process", "4"]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["pose_zones"] == 2 and run["agents_per_process"] == 4


@pytest.mark.parametrize("extra", [["--pose-zones", "-1"], ["--pose-zones", "-3", "--insecure"]])
def test_bad_pose_zone_options_exit_2_before_anything_starts(tmp_path, extra) -> None:
    assert run_cli(["run", str(TWO), "--out", str(tmp_path / "o"), "--quiet", *extra]) == 2
    assert not (tmp_path / "o" / "processes.json").exists()


def test_bench_runs_the_pose_paths_side_by_side_in_every_round_with_the_latency_split(tmp_path) -> None:
    out = tmp_path / "bench"
    assert run_cli(["bench", "--out", str(out), "--fleets", "4@20", "--pose-zones", "0,1",
                    "--duration", "1.5"]) == 0
    result = json.loads((out / "bench.json").read_text())
    assert result["pose_zones"] == [0, 1]
    assert [(f["round"], f["pose_zones"]) for f in result["fleets"]] == [(1, 0), (1, 1)]
    for f in result["fleets"]:
        assert f["commands"] > 0
        parts = f["latency_parts_ms_median"]
        assert parts["pose_in"] > 0 and f["world_publish_ms_median"] > 0
        assert parts["cmd_back"] == pytest.approx(parts["transport_rest"] - parts["pose_in"])
        ticked = f["tick_parts_ms_median"]  # where the agents' tick goes
        assert ticked["inbox"] > 0 and ticked["step"] > 0 and ticked["command"] > 0
        assert ticked["leader"] > 0  # the leader's ticks have their own part
    compared = result["pose_zones_compared"]
    assert [(c["fleet"], c["pose_zones"]) for c in compared] == [("4@20", 0), ("4@20", 1)]
    assert compared[0]["latency_ms_p50_ratio"] == 1.0
    assert compared[1]["latency_ms_p50"] == result["fleets"][1]["latency_ms_p50"]
    assert "pose paths side by side" in (out / "bench.txt").read_text()
    assert "the tick's parts" in (out / "bench.txt").read_text()


def test_bench_refuses_a_bad_pose_zone_list(tmp_path) -> None:
    assert run_cli(["bench", "--out", str(tmp_path / "b"), "--fleets", "4@20",
                    "--pose-zones", "0,x"]) == 2
    assert run_cli(["bench", "--out", str(tmp_path / "b"), "--pose-zones", "1"]) == 2  # no --fleets


def test_a_zone_router_holds_the_runs_access_control_a_robot_cannot_forge_another_robots_command(
        ) -> None:
    scenario = fleet_scenario(8, 0.05, 1.0)  # two formations: one per zone
    ids = scenario.robot_ids
    robots = {rid: scenario.formation_of(rid).name for rid in ids}
    leaders = {f.name: f.leader for f in scenario.formations}
    creds = acl.new_credentials([acl.CAMERA_USER, acl.VIEWER_USER, acl.ZONE_USER, *ids])
    rules = acl.fleet_acl(robots, leaders, P, manager_user=None, zone_user=acl.ZONE_USER)
    folder = Path(tempfile.mkdtemp(prefix="zone-acl-"))  # short: a Unix socket path
    dictionary = folder / "users.txt"
    acl.write_dictionary(dictionary, creds)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    link = f"{acl.ZONE_LINK}/{folder / 'router.sock'}"
    router = zenoh.open(zenoh.Config.from_json5(json.dumps(
        acl.router_config([endpoint, link], rules, dictionary))))
    sessions: list[zenoh.Session] = []
    heard: dict[str, list[str]] = {"viewer": [], "zone0": [], "zone1": []}

    def login(at: str, user: str, password: str | None = None) -> zenoh.Session:
        auth = creds[user] if password is None else acl.UsrPwdAuth(user, password)
        s = zenoh.open(zconf.make_config("client", connect=[at], auth=auth))
        sessions.append(s)
        return s

    try:
        with PoseZones(scenario, 2, endpoint,
                       security=ZoneSecurity(rules, dictionary, link, creds[acl.ZONE_USER])) as zones:
            mine, other = ids[0], ids[1]  # same formation, zone 0
            far = next(r for r in ids if zones.zone_of[r] == 1)
            assert zones.zone_of[mine] == zones.zone_of[other] == 0
            viewer = login(endpoint, acl.VIEWER_USER)
            viewer.declare_subscriber(keys.all_robots_key(P, keys.CMD),
                                      lambda smp: heard["viewer"].append(str(smp.key_expr)))
            for z in (0, 1):
                zones.sessions[z].declare_subscriber(
                    keys.all_robots_key(P, keys.CMD),
                    lambda smp, z=z: heard[f"zone{z}"].append(str(smp.key_expr)))
            robot = login(zones.endpoint_of(mine), mine)
            with pytest.raises(zenoh.ZError):  # a wrong password: the zone router refuses it
                login(zones.endpoint_of(mine), other, "not-the-password")
            time.sleep(1.0)  # the subscriptions reach every router
            for rid in (mine, other, far):  # its own command, then two forged ones
                robot.put(keys.cmd_key(P, rid), encode(Cmd(0.1, 0.0, 0.1, 0.0, 1.0)))
            time.sleep(1.0)
    finally:
        for s in sessions:
            s.close()
        router.close()
        shutil.rmtree(folder, ignore_errors=True)
    own = [keys.cmd_key(P, mine)]
    assert heard["zone0"] == own  # the zone router dropped both forged commands
    assert heard["zone1"] == own  # and relayed the robot's own one across zones
    assert heard["viewer"] == own  # and to the run's router

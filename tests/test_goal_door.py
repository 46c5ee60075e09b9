"""Goals a careless fleet manager sends, put straight on the goal key with the manager's
credentials (past ``formation goal``'s own check), or through ``formation goal`` where only the
leader can tell they are wrong (outside its world, inside a shelf), to a running ``formation run
--hold`` fleet on real Zenoh: the leader refuses them, says so on its status (``formation goal``
exits 1 naming why), no agent raises, and the formation still reaches a normal goal sent
afterwards; the summary counts the refusals per formation."""

from __future__ import annotations

import json
import signal
import time
import urllib.request

import pytest
import zenoh

from formation.commands import goal as navcmd
from runtime.testing import free_tcp_port, wait_for_matching
from tests.test_hold import start_fleet, wait_endpoint
from wire import keys
from wire.navigation import GoalMsg, encode_nav
from wire.zconf import ZenohSettings, read_auth_file

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

GOAL_A = (2.25, 0.25)


def _refusals(session, timeout: float = 60.0) -> int:
    """Formation A's refused-goal count on its leader's status."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = {s.formation: s for s in navcmd.query_status(session, "warehouse", timeout=1.0)}
        if "A" in found:
            return found["A"].refused
        time.sleep(0.2)
    raise AssertionError("formation A's leader never answered a status query")


def _put_raw_goals(endpoint: str, manager) -> None:
    """Two goals ``formation goal`` would not send, put raw; each waits until the leader's
    status counts its refusal (a put before the route to the leader's subscriber exists, or
    while the leader is busy, is not lost to a fixed sleep: one was, on a loaded machine)."""
    conf = ZenohSettings(mode="client", connect=(endpoint,),
                         auth=read_auth_file(manager).auth).to_config()
    route = tuple((0.3 + 0.005 * k, 0.3) for k in range(64))  # a GoalMsg holds 64: a plan not
    with zenoh.open(conf) as session:
        pub = session.declare_publisher(keys.goal_key("warehouse", "A"))
        wait_for_matching(pub, 60.0)  # the leader has subscribed
        for k, msg in enumerate((GoalMsg("A", 1e308, 1e308, None, (), time.time()),
                                 GoalMsg("A", 0.3, 0.3, None, route, time.time() + 0.001))):
            before = _refusals(session)
            deadline = time.monotonic() + 60.0
            while _refusals(session) <= before:  # put again until counted (counted once)
                assert time.monotonic() < deadline, f"raw goal {k} was never refused"
                pub.put(encode_nav(msg))
                time.sleep(1.0)
        pub.undeclare()


def _wait_reached(endpoint: str, manager, timeout: float) -> None:
    conf = ZenohSettings(mode="client", connect=(endpoint,),
                         auth=read_auth_file(manager).auth).to_config()
    with zenoh.open(conf) as session:
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            found = {s.formation: s for s in navcmd.query_status(session, "warehouse", timeout=1.0)}
            last = found.get("A")
            if last is not None and last.state == "reached" and (last.gx, last.gy) == GOAL_A:
                return
            time.sleep(0.5)
    raise AssertionError(f"formation A did not reach {GOAL_A}: {last}")


def _refused_by_the_leader(endpoint: str, manager, capsys) -> None:
    """Goals ``formation goal`` lets through (finite, inside the coordinate range) that A's
    leader refuses: outside its world, then inside the shelf. Each exits 1 as soon as the
    leader's status counts the refusal, naming why; ``formation status`` shows the count and
    the last reason."""
    auth = ["--connect", endpoint, "--auth", str(manager)]
    capsys.readouterr()
    for x, y, why in ((5000.0, 5000.0, "goal (5000, 5000) is outside the world"),
                      (1.3, 0.0, "within the safe distance of box 'shelf'")):
        # a long timeout: the refusal on the status ends the wait, not the timeout
        assert navcmd.main(["goal", "A", str(x), str(y), "--timeout", "120", *auth]) == 1
        err = capsys.readouterr().err
        assert "its leader refused it: " in err and why in err, err
    assert navcmd.main(["status", *auth]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("A: "))
    assert "goal(s) refused, the last: " in line and "box 'shelf'" in line, line


def _live_row(port: int, fid: str, ready, timeout: float = 60.0) -> dict:
    """Formation ``fid``'s row of the live page's ``/state`` once ``ready(row)``."""
    deadline = time.monotonic() + timeout
    row: dict = {}
    while time.monotonic() < deadline:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/state", timeout=5) as resp:
            frame = json.load(resp).get("frame") or {}
        row = next((r for r in frame.get("formations", []) if r["name"] == fid), {})
        if row and ready(row):
            return row
        time.sleep(0.3)
    raise AssertionError(f"the live page never showed it: {row}")


def test_absurd_goals_and_over_long_routes_are_refused_and_no_agent_raises(tmp_path, capsys):
    out = tmp_path / "run"
    port = free_tcp_port()
    proc = start_fleet(out, "--realtime", "--duration", "600", "--live", str(port))
    try:
        endpoint = wait_endpoint(proc, out)
        manager = out / "secure" / "manager.json5"
        _put_raw_goals(endpoint, manager)
        _refused_by_the_leader(endpoint, manager, capsys)
        row = _live_row(port, "A", lambda r: "box 'shelf'" in (r.get("refusal") or ""))
        assert row["refused"] >= 4 and row["leader"] == "a1", row  # the live page's table
        argv = ["goal", "A", *map(str, GOAL_A), "--connect", endpoint, "--timeout", "30",
                "--auth", str(manager)]
        assert navcmd.main(argv) == 0
        _wait_reached(endpoint, manager, timeout=300.0)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 0, (tmp_path / "fleet.log").read_text(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agents"]["tick_errors"] == 0
    assert summary["collisions"] == 0
    agents = [json.loads(p.read_text()) for p in sorted((out / "agents").glob("*.json"))]
    assert agents and not any(a.get("killed") or a.get("counters_lost") for a in agents)
    door = sum(a["nav"].get("goals_refused", 0) for a in agents)
    # the two raw goals, and the one outside the world (put again each second until refused)
    assert door >= 3, [a["nav"] for a in agents]
    goals = summary["goals_by_formation"]
    assert goals["B"] == {"taken": 0, "refused": 0, "last_refusal": None}
    assert goals["A"]["taken"] == 1 and goals["A"]["refused"] >= 4, goals
    assert "within the safe distance of box 'shelf'" in goals["A"]["last_refusal"], goals

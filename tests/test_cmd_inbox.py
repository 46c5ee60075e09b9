"""The world's command inbox in lock-step: which robots a tick's step waits for (late robots,
a restarted agent that never saw the tick's poses) and which missing commands it counts."""

from __future__ import annotations

import threading

from simulator.cmd_inbox import CmdInbox
from wire import keys
from wire.payloads import Cmd
from wire.traffic import TrafficCounter

ROBOTS = ("a", "b", "c")


def inbox() -> CmdInbox:
    return CmdInbox(keys.DEFAULT_PREFIX, TrafficCounter(), ROBOTS)


def command(box: CmdInbox, rid: str, t: float) -> None:
    box.offer(rid, Cmd(0.1, 0.0, 0.1, 0.0, t), keys.cmd_key(keys.DEFAULT_PREFIX, rid), 40)


def ready_at(box: CmdInbox, t: float):
    """The world's step barrier for the tick stamped ``t``."""
    return lambda: box.all_in(t, ROBOTS)


def test_a_robot_whose_command_timed_out_is_late_until_one_arrives():
    box = inbox()
    box.begin_tick(0.0)
    command(box, "a", 0.0)
    command(box, "b", 0.0)
    assert not box.wait(ready_at(box, 0.0), 0.01, lambda: None)  # c never answers
    got, late = box.take_since(0.0, ROBOTS)
    assert set(got) == {"a", "b"} and late == ["c"]
    box.begin_tick(0.05)
    command(box, "a", 0.05)
    command(box, "b", 0.05)
    assert box.wait(ready_at(box, 0.05), 5.0, lambda: None)  # c is not waited for again
    assert box.take_since(0.05, ROBOTS)[1] == []  # nor counted late twice
    command(box, "c", 0.05)
    assert box.waited_for("c")  # its command came back: waited for again


def test_a_restarted_agent_is_excused_for_the_tick_under_way_and_waited_for_from_the_next():
    box = inbox()
    box.begin_tick(0.0)
    command(box, "a", 0.0)
    command(box, "b", 0.0)
    box.excuse("c")  # restarted while the world waited: it never saw this tick's poses
    assert box.wait(ready_at(box, 0.0), 5.0, lambda: None)
    got, late = box.take_since(0.0, ROBOTS)
    assert "c" not in got and late == []  # not marked late: the next tick waits for it
    box.begin_tick(0.05)
    assert box.waited_for("c")
    command(box, "a", 0.05)
    command(box, "b", 0.05)
    assert not box.wait(ready_at(box, 0.05), 0.01, lambda: None)  # waits for c now
    threading.Timer(0.05, command, (box, "c", 0.05)).start()
    assert box.wait(ready_at(box, 0.05), 5.0, lambda: None)


def test_excusing_a_late_robot_makes_it_waited_for_from_the_next_tick():
    box = inbox()
    box.begin_tick(0.0)
    assert not box.wait(ready_at(box, 0.0), 0.01, lambda: None)
    assert sorted(box.take_since(0.0, ROBOTS)[1]) == list(ROBOTS)  # all late
    box.begin_tick(0.05)
    box.excuse("b")
    assert not box.waited_for("b")
    box.begin_tick(0.1)
    assert box.waited_for("b") and not box.waited_for("a")

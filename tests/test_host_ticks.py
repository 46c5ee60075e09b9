"""agent.host's tick thread: the garbage collector's due collection runs between ticks, when no
node is queued, and is as small as Python's own young collection."""

from __future__ import annotations

import gc
import threading
from typing import cast

from agent.host import HostedNode, TickWorker, collect_if_due


def test_a_due_young_collection_is_made_and_an_early_one_is_not() -> None:
    before = gc.get_threshold()
    try:
        gc.set_threshold(1_000_000, 10, 10)  # the automatic one out of the way
        gc.collect()
        kept = [[] for _ in range(50)]  # tracked objects: the young count grows
        assert collect_if_due(young=10_000) is None  # not due
        assert gc.get_count()[0] >= 50
        assert collect_if_due(young=50) is not None  # due: collected
        assert gc.get_count()[0] < 50
        del kept
    finally:
        gc.set_threshold(*before)


def test_an_older_generation_is_collected_when_its_own_count_passes_its_threshold() -> None:
    before = gc.get_threshold()
    try:
        gc.set_threshold(1_000_000, 2, 1_000_000)
        gc.collect()
        for _ in range(2):  # two young collections: the middle generation's count reaches 2
            gc.collect(0)
        kept = [[] for _ in range(20)]
        assert collect_if_due(young=10) == 1
        assert gc.get_count()[1] == 0
        del kept
    finally:
        gc.set_threshold(*before)


def test_a_disabled_collector_stays_off() -> None:
    was, before = gc.isenabled(), gc.get_threshold()
    kept = [[] for _ in range(50)]
    try:
        gc.disable()
        assert collect_if_due(young=10) is None
        gc.enable()
        gc.set_threshold(0, 10, 10)  # switched off by its threshold
        assert collect_if_due(young=10) is None
        assert gc.get_count()[0] >= 10
    finally:
        gc.set_threshold(*before)
        if was:
            gc.enable()
        del kept


class FakeNode:
    """What the tick thread uses of a hosted node: ``tick_queued`` and ``superseded``."""

    def __init__(self, release: threading.Event, ticked: list[str], name: str) -> None:
        self.superseded = 0
        self.release = release
        self.ticked = ticked
        self.name = name

    def tick_queued(self) -> None:
        self.release.wait(10.0)
        self.ticked.append(self.name)


def test_the_tick_thread_collects_only_when_no_node_waits() -> None:
    events: list[str] = []
    idle_done = threading.Event()

    def idle() -> None:
        events.append("idle")
        idle_done.set()

    release = threading.Event()
    worker = TickWorker(idle)
    try:
        a = FakeNode(release, events, "a")
        b = FakeNode(release, events, "b")
        worker.mark(cast(HostedNode, a))  # a's tick holds the thread until released
        worker.mark(cast(HostedNode, b))  # b waits behind it
        worker.mark(cast(HostedNode, b))  # a newer pose of b: superseded, not queued twice
        release.set()
        assert idle_done.wait(10.0)
        assert events == ["a", "b", "idle"]  # no collection between a and b: b was waiting
        assert b.superseded == 1
    finally:
        worker.stop()

"""What a lock-step agent reads without waiting for it is in before the tick that reads it.

An agent waits for its formation inputs by stamp, but reads its teammates' states and
statuses, its leader's plans and the world's loads as they came: each was put before its
sender's command of tick ``k - 1``, so through the run's router it reaches the agent before the
world's pose of tick ``k``. That holds only when the agent takes the samples in the order its
link brought them (:func:`wire.traffic.in_order`); zenoh-python's default hands each subscriber
its own Python thread, and a tick could begin before a slow one was taken. Real sessions through
a router on loopback, as ``formation run`` connects them; the first callback is made slow so
that taking out of order would show.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest
import zenoh

from agent.bidder import Bidder, BidderSettings
from agent.faults import LinkFaults
from agent.order_link import OrderLink
from runtime.testing import RouterProcess, wait_for_matching
from wire import keys
from wire.orders import OrderStatusMsg, encode_order, order_status_key
from wire.traffic import in_order
from wire.zconf import ZenohSettings

P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0
SLOW_S = 0.3  # a callback this slow is overtaken by the next key's when taken out of order


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as r:
        yield r


def session(router: RouterProcess) -> zenoh.Session:
    return zenoh.open(ZenohSettings(mode="client", connect=(router.endpoint,),
                                    multicast_scouting=False).to_config())


def slowed(callback: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], None]:
    def slow(sample: zenoh.Sample) -> None:
        time.sleep(SLOW_S)
        callback(sample)
    return slow


def test_samples_on_two_keys_are_taken_in_the_order_the_link_brought_them(router) -> None:
    taken: list[str] = []
    second = threading.Event()

    def first_cb(sample: zenoh.Sample) -> None:
        taken.append(str(sample.key_expr))

    def second_cb(sample: zenoh.Sample) -> None:
        taken.append(str(sample.key_expr))
        second.set()

    with session(router) as receiver, session(router) as sender:
        subs = [receiver.declare_subscriber("t/first", in_order(slowed(first_cb))),
                receiver.declare_subscriber("t/pose", in_order(second_cb))]
        pubs = [sender.declare_publisher(k) for k in ("t/first", "t/pose")]
        for pub in pubs:
            wait_for_matching(pub)
        for pub in pubs:
            pub.put(b"x")
        assert second.wait(TIMEOUT_S)
        for handle in [*pubs, *subs]:
            handle.undeclare()
    assert taken == ["t/first", "t/pose"]


class SlowSession:
    """A session whose subscribers take each sample ``SLOW_S`` late, on the thread and in the
    way the subscriber's own handler asked for (direct or on a Python thread of its own)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session

    def declare_subscriber(self, key: str, handler):
        if isinstance(handler, zenoh.handlers.Callback):
            handler = zenoh.handlers.Callback(slowed(handler.callback), indirect=handler.indirect)
        else:
            handler = slowed(handler)
        return self.session.declare_subscriber(key, handler)

    def declare_publisher(self, key: str):
        return self.session.declare_publisher(key)


def test_a_status_put_before_the_pose_has_reached_the_order_link_when_the_pose_does(
        router) -> None:
    """The order link takes a teammate's status before a pose that came after it over the same
    link, however slow taking the status is: the tick the pose starts hears it."""
    received_at_pose: list[int] = []
    posed = threading.Event()
    with session(router) as robot, session(router) as others:
        link = OrderLink(SlowSession(robot), P, Bidder("r1", BidderSettings(fleet_size=2)),
                         lambda m: None, LinkFaults())

        def on_pose(sample: zenoh.Sample) -> None:
            received_at_pose.append(link.received)
            posed.set()

        pose_sub = robot.declare_subscriber(keys.pose_key(P, "r1"), in_order(on_pose))
        status_pub = others.declare_publisher(order_status_key(P, "o1"))
        pose_pub = others.declare_publisher(keys.pose_key(P, "r1"))
        for pub in (status_pub, pose_pub):
            wait_for_matching(pub)
        status_pub.put(encode_order(OrderStatusMsg("o1", "carrying", 1, ("r2", "r1"), "r2",
                                                   stamp=0.0)))
        pose_pub.put(b"pose")
        assert posed.wait(TIMEOUT_S)
        for handle in (status_pub, pose_pub, pose_sub):
            handle.undeclare()
        link.close()
    assert received_at_pose == [1]

"""Loopback round-trip time of a ``State`` payload through a Zenoh router.

A Python router runs in a child process (``python -m runtime.router``); this process opens two
client sessions: *ping* puts a State on ``warehouse/robot/ping/state``, *pong* echoes every
sample it receives onto ``warehouse/robot/pong/state``, and ping times the reply. Warm-up, then
N samples, one summary line (the shape of zenoh's ``z_ping``)::

    python3 benchmarks/zenoh_roundtrip.py [--samples 1000] [--warmup 100] [--direct]

``--direct`` connects two peer sessions to each other without a router, for comparison.
"""

from __future__ import annotations

import argparse
import contextlib
import queue
import statistics
import sys
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import zenoh

from runtime.testing import (
    RouterProcess,
    free_tcp_port,
    tcp_endpoint,
    wait_for_matching,
)
from wire import keys, zconf
from wire.payloads import State, decode_state, encode

REPLY_TIMEOUT_S = 5.0


@contextlib.contextmanager
def session_pair(direct: bool) -> Iterator[tuple[zenoh.Session, zenoh.Session, str]]:
    """Two open sessions (ping, pong) and a description of the path between them."""
    with contextlib.ExitStack() as stack:
        if direct:
            endpoint = tcp_endpoint(free_tcp_port())
            a = zenoh.open(zconf.make_config("peer", listen=[endpoint], scouting_delay_s=0.0))
            stack.callback(a.close)
            b = zenoh.open(
                zconf.make_config(
                    "peer", connect=[endpoint], scouting_delay_s=0.0, connect_timeout_s=5.0
                )
            )
            stack.callback(b.close)
            path = f"peer to peer over {endpoint}"
        else:
            router = stack.enter_context(RouterProcess())
            conf = zconf.make_config("client", connect=[router.endpoint], connect_timeout_s=5.0)
            a = zenoh.open(conf)
            stack.callback(a.close)
            b = zenoh.open(conf)
            stack.callback(b.close)
            path = f"client -> router process ({router.endpoint}) -> client"
        yield a, b, path


def measure(samples: int, warmup: int, direct: bool) -> tuple[list[float], int, str]:
    """Round-trip times in seconds, the payload size in bytes and the path description."""
    ping_key = keys.state_key(keys.DEFAULT_PREFIX, "ping")
    pong_key = keys.state_key(keys.DEFAULT_PREFIX, "pong")
    replies: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    rtts: list[float] = []
    with session_pair(direct) as (ping, pong, path):
        echo = pong.declare_publisher(pong_key)
        pong.declare_subscriber(ping_key, lambda s: echo.put(s.payload))
        ping.declare_subscriber(pong_key, lambda s: replies.put(s.payload.to_bytes()))
        out = ping.declare_publisher(ping_key)
        wait_for_matching(out)
        wait_for_matching(echo)
        payload = encode(State(1.0, 2.0, 0.1, -0.1, time.time()))
        for i in range(warmup + samples):
            start = time.perf_counter()
            out.put(payload)
            reply = replies.get(timeout=REPLY_TIMEOUT_S)
            elapsed = time.perf_counter() - start
            if i >= warmup:
                rtts.append(elapsed)
        decode_state(reply)  # the echo is still a valid State
    return rtts, len(payload), path


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q / 100.0 * (len(ordered) - 1))))
    return ordered[index]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--direct", action="store_true", help="two peers, no router")
    ns = parser.parse_args(argv)
    if ns.samples < 1 or ns.warmup < 0:
        print("samples must be >= 1 and warmup >= 0", file=sys.stderr)
        return 2
    rtts, size, path = measure(ns.samples, ns.warmup, ns.direct)
    us = [t * 1e6 for t in rtts]
    print(
        f"State payload {size} B, {path}: {len(us)} round trips after {ns.warmup} warm-up: "
        f"median {statistics.median(us):.0f} us, p99 {percentile(us, 99):.0f} us, "
        f"min {min(us):.0f} us, max {max(us):.0f} us"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

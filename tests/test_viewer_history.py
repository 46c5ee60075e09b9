"""The live page's barrier history on the server (viewer.server): a bounded ring of the frames'
barrier values that ``GET /history`` hands a page when it (re)loads. The page itself, reloaded
in a real browser, is in tests/test_viewer_live.py."""

from __future__ import annotations

import json
import math
import urllib.request

from hypothesis import given, settings
from hypothesis import strategies as st

from viewer.server import HISTORY_S, HISTORY_SAMPLES, HISTORY_STEP_S, BarrierHistory, Hub, PageServer


def frame(t: float, h: float | None = 0.5, robots: tuple[str, ...] = ("a1", "b1")) -> dict:
    return {"t": t, "robots": [{"id": rid, "formation": rid[0].upper(), "status": "ok",
                                "h_formation": h, "h_obstacle": 1.0, "h_formations": None}
                               for rid in robots]}


def test_the_cap_is_ten_minutes_at_the_pages_poll_rate():
    assert HISTORY_S == 600.0 and HISTORY_STEP_S == 0.1 and HISTORY_SAMPLES == 6000


def test_history_is_served_from_the_runs_first_frame_per_robot_with_its_barrier_values():
    hub = Hub()
    for k in range(40):  # 2.5 s at 16 Hz: one sample per 0.1 s kept, every other frame
        hub.publish(frame(10.0 + k / 16, h=0.5 - 0.01 * k))
    server = PageServer(hub)
    try:
        with urllib.request.urlopen(server.url + "history", timeout=10) as resp:
            got = json.load(resp)
    finally:
        server.close()
    assert got["seq"] == 40 and got["span_s"] == HISTORY_S
    assert set(got["robots"]) == {"a1", "b1"} and got["robots"]["b1"]["formation"] == "B"
    pts = got["robots"]["a1"]["pts"]
    assert [p[0] for p in pts] == [10.0 + k / 8 for k in range(20)]
    assert pts[0][1:] == [0.5, 1.0, None] and pts[-1][1] == 0.5 - 0.01 * 38


def test_non_finite_barriers_are_sent_as_null_and_a_replay_sought_back_starts_afresh():
    history = BarrierHistory()
    history.add(frame(0.0, h=math.nan))
    history.add(frame(5.0, h=math.inf))
    assert [row[2] for _, rows in history.samples() for row in rows] == [None] * 4
    json.dumps(BarrierHistory.by_robot(history.samples()), allow_nan=False)
    history.add(frame(2.0))  # back in time: the page clears its plots too
    assert [t for t, _ in history.samples()] == [2.0]


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.floats(0.0, 3.0), min_size=1, max_size=300),
       span=st.floats(0.5, 20.0), step=st.floats(0.0, 0.5), cap=st.integers(1, 50))
def test_the_ring_stays_within_its_span_its_cap_and_its_step(steps, span, step, cap):
    history = BarrierHistory(span_s=span, step_s=step, cap=cap)
    t = 0.0
    for dt in steps:
        t += dt
        history.add(frame(t))
    times = [s[0] for s in history.samples()]
    assert 1 <= len(times) <= cap
    assert times[-1] - times[0] <= span + 1e-9
    assert all(b - a >= step - 1e-9 for a, b in zip(times, times[1:], strict=False))
    assert t - times[-1] < step + 1e-9  # the newest sample is at most a step behind

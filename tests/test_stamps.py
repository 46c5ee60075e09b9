"""The one stamp check (wire.stamps): reasons in order, nothing blocked by a refused stamp."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from wire.stamps import (
    CLOCK_TOLERANCE_S,
    FUTURE,
    OLDER,
    REASONS,
    STALE,
    StampCounter,
    check_stamp,
    merge_counts,
    used_stamp,
    validate_window,
)

times = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
spans = st.floats(min_value=1e-3, max_value=10.0)


def test_each_reason_in_its_place():
    assert check_stamp(10.0, 10.0, 9.9, 0.1, 0.25) is None
    assert check_stamp(10.0, 10.05, None, 0.1, 0.25) is None  # ahead, within the tolerance
    assert check_stamp(10.0, 10.2, None, 0.1, 0.25) == FUTURE
    assert check_stamp(10.0, 9.7, None, 0.1, 0.25) == STALE
    assert check_stamp(10.0, 9.9, 9.95, 0.1, 0.25) == OLDER
    assert check_stamp(10.0, 9.95, 9.95, 0.1, 0.25) is None  # the same stamp again is not older
    assert check_stamp(10.0, math.inf, None, 0.1, 0.25) == FUTURE
    assert check_stamp(10.0, -math.inf, None, 0.1, 0.25) == STALE


@given(now=times, stamp=times, last=st.none() | times, tol=spans, stale=spans)
def test_the_reasons_are_checked_in_the_order_future_stale_older(now, stamp, last, tol, stale):
    got = check_stamp(now, stamp, last, tol, stale)
    future = stamp > now + tol + 1e-9
    too_old = now - stamp > stale + 1e-9
    older = last is not None and stamp < last - 1e-9
    if future:
        assert got == FUTURE
    elif too_old:
        assert got == STALE
    elif older:
        assert got == OLDER
    else:
        assert got is None


@given(stamps=st.lists(st.floats(min_value=0.0, max_value=100.0), min_size=1, max_size=30),
       forged=st.floats(min_value=1e3, max_value=1e12))
def test_one_future_stamp_never_blocks_the_genuine_ones_after_it(stamps, forged):
    # a receiver that keeps the last accepted stamp, fed a camera's increasing stamps with one
    # forged future stamp in the middle, accepts exactly what it accepts without the forgery
    def accepted(seq: list[float]) -> list[float]:
        last, out = None, []
        for now, s in seq:
            if check_stamp(now, s, last, 0.1, 0.5) is None:
                last = s
                out.append(s)
        return out

    clean = [(s, s) for s in sorted(stamps)]
    mid = len(clean) // 2
    attacked = clean[:mid] + [(clean[mid - 1][0] if mid else 0.0, forged)] + clean[mid:]
    assert accepted(attacked) == accepted(clean) == sorted(stamps)


def test_rejections_are_counted_per_class_and_reason_and_merge_across_processes():
    c = StampCounter()
    assert c.check("pose", 10.0, 10.0, None, 0.1, 0.25)
    assert not c.check("pose", 10.0, 1e9, None, 0.1, 0.25)
    assert not c.check("pose", 10.0, 8.0, None, 0.1, 0.25)
    assert not c.check("state", 10.0, 9.9, 10.0, 0.1, 0.25)
    assert c.snapshot() == {"pose": {FUTURE: 1, STALE: 1, OLDER: 0},
                            "state": {FUTURE: 0, STALE: 0, OLDER: 1}}
    assert c.total == 3
    assert merge_counts([c.snapshot(), c.snapshot()])["pose"] == {FUTURE: 2, STALE: 2, OLDER: 0}
    assert REASONS == (FUTURE, STALE, OLDER)
    with pytest.raises(ValueError, match="reason"):
        c.count("pose", "late")


@pytest.mark.parametrize("tol, stale, name", [(0.0, 1.0, "clock_tolerance"),
                                              (math.nan, 1.0, "clock_tolerance"),
                                              (0.1, -1.0, "stale_after")])
def test_a_bad_window_names_its_parameter(tol, stale, name):
    with pytest.raises(ValueError, match=name):
        validate_window(tol, stale)


def _stream(period: float, latency: float, forged_at: set[int], ahead: float, n: int,
            clamp: bool) -> list[bool]:
    """A receiver fed one genuine message per period (stamped ``latency`` before it arrives) and,
    right after genuine message k for k in ``forged_at``, a forged one stamped ``ahead`` past
    the receiver's clock. Returns whether each genuine message was accepted."""
    last: float | None = None
    accepted = []
    for k in range(n):
        now = k * period
        ok = check_stamp(now, now - latency, last, CLOCK_TOLERANCE_S, 1.0) is None
        if ok:
            last = now - latency
        accepted.append(ok)
        if k in forged_at:
            now_f = now + 1e-3
            stamp = now_f + ahead
            if check_stamp(now_f, stamp, last, CLOCK_TOLERANCE_S, 1.0) is None:
                last = used_stamp(now_f, stamp) if clamp else stamp
    return accepted


@given(period=st.floats(0.02, 0.2), latency_frac=st.floats(0.0, 0.95),
       ahead=st.floats(0.0, CLOCK_TOLERANCE_S * 0.99),
       forged=st.sets(st.integers(0, 39), max_size=40))
def test_a_message_stamped_ahead_refuses_at_most_the_next_genuine_one(period, latency_frac, ahead,
                                                                      forged):
    # issue 28: a message stamped 90 ms ahead (inside the tolerance) took over its stream
    accepted = _stream(period, latency_frac * period, forged, ahead, 40, clamp=True)
    refused = [k for k, ok in enumerate(accepted) if not ok]
    assert all(k - 1 in forged for k in refused)  # only right after a forged message
    assert accepted[0]


def test_recorded_as_it_came_a_forged_stream_hides_every_genuine_message():
    # the attack of issue 28 on the old rule, for contrast: forged after every genuine message
    every = set(range(40))
    assert sum(_stream(0.05, 0.02, every, 0.09, 40, clamp=False)) == 1  # only the first
    assert all(_stream(0.05, 0.02, every, 0.09, 40, clamp=True))

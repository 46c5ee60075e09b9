"""The spacing rule of real time on pose arrival (agent.schedule.pose_due): which poses an agent
ticks on, by their stamps alone."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from agent.schedule import LATE_POSE_PERIODS, MIN_SPACING_PERIODS, pose_due

T = 0.05  # [s] the control period of the bench fleets (20 Hz)


def ticked(stamps: list[float], period: float = T) -> list[float]:
    """The stamps an agent ticks on when its poses arrive in this order."""
    anchor, out = None, []
    for s in stamps:
        new = pose_due(anchor, s, period)
        if new is not None:
            anchor = new
            out.append(s)
    return out


def test_a_pose_stamped_late_does_not_make_the_next_punctual_one_too_soon() -> None:
    # the world lost the CPU for 15 ms before stamping pose 1: pose 2, on time, is 35 ms
    # after it, less than MIN_SPACING_PERIODS (37.5 ms); ruled by the last ticked stamp it was
    # never ticked on (16 robots of one pose slot missed a tick at once in the 2-core bench)
    stamps = [0.0, T + 0.015, 2 * T, 3 * T]
    assert ticked(stamps) == stamps
    assert 2 * T - (T + 0.015) < MIN_SPACING_PERIODS * T


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 0.749 * T), min_size=1, max_size=60))
def test_a_camera_at_the_control_rate_ticks_on_every_pose_stamped_up_to_075_periods_late(
        delays) -> None:
    stamps = [0.0] + [(k + 1) * T + d for k, d in enumerate(delays)]  # after one on time
    assert ticked(stamps) == stamps


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 0.2), min_size=1, max_size=80), st.floats(0.01, 0.1))
def test_a_faster_camera_never_raises_the_tick_rate(gaps, period) -> None:
    # any increasing stamps (a camera of any rate, with any jitter): the ticks of any window of
    # W seconds number at most (W + LATE_POSE_PERIODS * period) / (MIN_SPACING_PERIODS * period)
    # + 1, since the schedule advances at least MIN_SPACING_PERIODS per tick and lags a ticked
    # stamp by at most LATE_POSE_PERIODS
    stamps, t = [], 100.0
    for g in gaps:
        t += g
        stamps.append(t)
    ts = ticked(stamps, period)
    for i, a in enumerate(ts):
        for j in range(i, len(ts)):
            w = ts[j] - a
            bound = (w + LATE_POSE_PERIODS * period) / (MIN_SPACING_PERIODS * period) + 1
            assert j - i + 1 <= bound + 1e-9


def test_a_camera_twice_as_fast_ticks_on_every_other_pose() -> None:
    stamps = [k * T / 2 for k in range(40)]
    assert ticked(stamps) == stamps[::2]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 0.2), min_size=1, max_size=40))
def test_the_same_pose_twice_ticks_once(gaps) -> None:
    anchor, t = None, 50.0
    for g in gaps:
        t += g
        new = pose_due(anchor, t, T)
        if new is not None:
            anchor = new
            assert pose_due(anchor, t, T) is None


def test_a_camera_clock_that_goes_back_starts_a_new_schedule() -> None:
    anchor = pose_due(None, 10.0, T)
    assert anchor == 10.0
    assert pose_due(anchor, 9.0, T) == 9.0  # earlier than the schedule: due, the new anchor

"""The leader's book of the other leaders' statuses (agent.navigation.StatusBook): a lock-step
leader reads what was reported before its tick, whatever order the statuses came in, so the
tick's decision does not hang on whether another process's status of the same tick arrived
first; in real time it reads the newest."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from agent.navigation import REPORT_MAX_AGE_S, StatusBook
from wire.navigation import StatusMsg
from wire.payloads import EllipseMsg

SEEN = (EllipseMsg("f2", 1.0, 2.0, 0.0, 0.5, 0.3, 0.0, 0.0, 0.0, 3.0),)


def status(stamp: float, state: str, gx: float = 4.0) -> StatusMsg:
    return StatusMsg("f2", state, "r2", 0.0, gx, 5.0, None, 1.0, 0, 2, gx, 5.0, stamp)


def test_a_lock_step_tick_reads_the_status_put_before_it_and_real_time_the_newest() -> None:
    book = StatusBook()
    book.hear(status(2.0, "moving"))
    book.hear(status(3.0, "unreachable"))  # put by f2's leader during the tick stamped 3.0
    lock = book.view(3.0, SEEN, lockstep=True)["f2"]
    assert lock.state == "moving" and lock[1:] == (1.0, 2.0, 4.0, 5.0, 0.5)
    assert book.view(3.0, SEEN, lockstep=False)["f2"].state == "unreachable"
    assert book.view(3.05, SEEN, lockstep=True)["f2"].state == "unreachable"  # the next tick


def test_only_formations_in_view_with_a_recent_status_are_reported() -> None:
    book = StatusBook()
    assert book.view(3.0, SEEN, lockstep=False) == {}
    book.hear(status(1.0, "moving"))
    assert book.view(1.0, SEEN, lockstep=True) == {}  # nothing before the first status
    assert book.view(1.0 + REPORT_MAX_AGE_S + 0.05, SEEN, lockstep=False) == {}
    assert book.view(3.0, (), lockstep=False) == {}


@given(st.permutations([1.0, 2.0, 3.0, 4.0, 5.0]))
def test_the_two_newest_stamps_are_kept_in_any_order_of_arrival(order: list[float]) -> None:
    book = StatusBook()
    for s in order:
        book.hear(status(s, "moving", gx=s))  # its goal tells it apart
    book.hear(status(5.0, "reached", gx=5.0))  # the same tick's again (a queryable's answer)
    assert book.view(5.0, SEEN, lockstep=False)["f2"][::3] == ("reached", 5.0)
    assert book.view(5.0, SEEN, lockstep=True)["f2"][::3] == ("moving", 4.0)

"""A lifelong run's progress line shows the orders delivered, drawn again at each delivery."""

from __future__ import annotations

from formation.progress import Progress


def _lines(err: str) -> list[str]:
    return [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]


def test_the_line_counts_the_orders_delivered_and_shows_each_delivery(capsys):
    with Progress("sim hall", early="every order done") as p:
        for k in range(1, 401):  # 400 of 1000 ticks; deliveries at ticks 123 and 257
            p.orders((k >= 123) + (k >= 257), 3)
            p.update(k, 1000, k * 0.05)
    lines = _lines(capsys.readouterr().err)
    # the bar is drawn every 10 % off a terminal, and at once at each delivery
    assert [ln for ln in lines if "1/3 orders" in ln][0].count("#") == 3  # at 12 %, not 20 %
    assert any("t=  12.85 s" in ln and "2/3 orders delivered" in ln for ln in lines)
    assert lines[-1].endswith("2/3 orders delivered: every order done")


def test_a_run_without_orders_shows_none(capsys):
    with Progress("sim x") as p:
        for k in range(1, 11):
            p.update(k, 10, k * 0.05)
    lines = _lines(capsys.readouterr().err)
    assert lines and not any("orders" in ln for ln in lines)

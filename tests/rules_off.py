"""Test helper: the in-process simulator with some of the controller's rules switched off, to
show what a rule does (the same scenario with it and without it)."""

from __future__ import annotations

from dataclasses import replace

from simulator import inprocess


def params_with(monkeypatch, **changes) -> None:
    """Every ``ControlParams`` the simulator builds from a scenario gets ``changes`` (e.g.
    ``shape_clear=False``) for the rest of the test."""
    build = inprocess.ControlParams.from_scenario
    monkeypatch.setattr(inprocess.ControlParams, "from_scenario",
                        lambda sc, safety=True: replace(build(sc, safety), **changes))

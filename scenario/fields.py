"""The field checks every part of a scenario file shares: a mapping with known keys, a number
(finite, in its :class:`scenario.limits.Range`), a vector, a string, a name, a title.

Each raises :class:`scenario.reader.ScenarioError` naming the culprit by its path in the file
(``where``) and quoting at most a short excerpt of the value.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from wire.keys import name_problem

from . import limits
from .limits import Range
from .reader import EXCERPT_CHARS, ScenarioError, excerpt


def mapping(raw: Any, where: str, allowed: set[str]) -> Mapping[str, Any]:
    if raw is None:
        raw = {}
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{where}: must be a mapping, got {type(raw).__name__}")
    for key in raw:
        if key not in allowed:
            # a key longer than every known one is no misspelling: the known list would not help
            longest = max((len(k) for k in allowed), default=0)
            known = ("longer than any known key" if len(str(key)) > max(longest, EXCERPT_CHARS)
                     else f"known: {', '.join(sorted(allowed))}")
            raise ScenarioError(
                f"{where}: unknown key {excerpt(key)} ({known})"
                if where != "scenario"
                else f"unknown key {excerpt(key)} ({known})"
            )
    return raw


def count(items: Any, where: str, most: int) -> None:
    if len(items) > most:
        raise ScenarioError(f"{where}: {len(items)} entries, more than the {most} allowed")


def number(raw: Any, where: str) -> float:
    """A finite number (:func:`scenario.limits.number`)."""
    return limits.number(raw, where, ScenarioError)


def positive(raw: Any, where: str) -> float:
    v = number(raw, where)
    if v <= 0.0:
        raise ScenarioError(f"{where}: must be positive, got {excerpt(raw)}")
    return v


def within(raw: Any, where: str, allowed: Range) -> float:
    """A finite number in ``allowed`` (:func:`scenario.limits.check`: a non-positive one where
    only positive ones make sense is reported as such, with the range)."""
    return limits.check(raw, where, allowed, ScenarioError)


def vector(raw: Any, where: str, lengths: tuple[int, ...],
            allowed: Range | None = None) -> tuple[float, ...]:
    if not isinstance(raw, list | tuple) or len(raw) not in lengths:
        want = " or ".join(str(n) for n in lengths)
        raise ScenarioError(f"{where}: must be a list of {want} numbers, got {excerpt(raw)}")
    values = tuple(number(v, f"{where}[{k}]") for k, v in enumerate(raw))
    if allowed is not None:
        for k, v in enumerate(values[:2]):
            within(v, f"{where}[{k}]", allowed)
    return values


def string(raw: Any, where: str) -> str:
    if isinstance(raw, bool) or not isinstance(raw, str | int):
        raise ScenarioError(f"{where}: must be a string, got {excerpt(raw)}")
    if isinstance(raw, int) and abs(raw) >= 10**18:
        raise ScenarioError(f"{where}: must be a string, got {excerpt(raw)}")
    return str(raw)


def identifier(raw: Any, where: str) -> str:
    """A robot, formation or obstacle name: :func:`wire.keys.name_problem`, the rule that
    ``formation run`` and ``deploy`` apply too."""
    s = string(raw, where)
    problem = name_problem(s)
    if problem is not None:
        raise ScenarioError(f"{where}: {excerpt(s)} is not a valid name: it {problem}")
    return s


def title(raw: Any, where: str) -> str:
    """The scenario's own name: printable, at most 128 characters (it labels runs and plots)."""
    s = string(raw, where)
    if len(s) > 128 or not s.isprintable():
        raise ScenarioError(f"{where}: {excerpt(s)} must be printable and at most 128 "
                            "characters")
    return s

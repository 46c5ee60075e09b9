"""An argument parser that keeps, where others may read them, the arguments and subcommands it
was given: argparse keeps them only in private attributes, and the command-line reference
(:mod:`formation.clidoc`) and its tests read them.

``Parser`` is an ``argparse.ArgumentParser``; its subcommands' parsers are ``Parser`` too (argparse
makes them of the parent's class).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Argument:
    """An argument as it was added: its action, and what kind (``action=`` of ``add_argument``:
    ``"store"``, ``"append"``, ``"help"``...; ``"parsers"`` for the subcommands)."""

    action: argparse.Action
    kind: str


@dataclass(frozen=True)
class Command:
    """A subcommand: its parser and its one-line help."""

    parser: Parser
    help: str


class Parser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` with ``arguments`` (every argument in the order added, the
    automatic ``--help`` included, groups' too) and ``commands`` (name -> :class:`Command`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.arguments: list[Argument] = []
        self.commands: dict[str, Command] = {}
        super().__init__(*args, **kwargs)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        self.arguments.append(Argument(action, _kind(kwargs.get("action", "store"))))
        return action

    def add_mutually_exclusive_group(self, **kwargs: Any) -> Any:
        group = super().add_mutually_exclusive_group(**kwargs)
        setattr(group, "add_argument", self._recording(group.add_argument))  # noqa: B010 - a method
        return group

    def add_argument_group(self, *args: Any, **kwargs: Any) -> Any:
        group = super().add_argument_group(*args, **kwargs)
        setattr(group, "add_argument", self._recording(group.add_argument))  # noqa: B010 - a method
        return group

    def add_subparsers(self, **kwargs: Any) -> Any:
        sub = super().add_subparsers(**kwargs)
        self.arguments.append(Argument(sub, "parsers"))
        add_parser = sub.add_parser

        def recorded(name: str, **options: Any) -> argparse.ArgumentParser:
            parser = add_parser(name, **options)
            if isinstance(parser, Parser):
                self.commands[name] = Command(parser, options.get("help") or "")
            return parser

        setattr(sub, "add_parser", recorded)  # noqa: B010 - a method
        return sub

    def _recording(self, add: Callable[..., argparse.Action]) -> Callable[..., argparse.Action]:
        """``add`` (a group's ``add_argument``), keeping what it adds in :attr:`arguments`."""

        def recorded(*args: Any, **kwargs: Any) -> argparse.Action:
            action = add(*args, **kwargs)
            self.arguments.append(Argument(action, _kind(kwargs.get("action", "store"))))
            return action

        return recorded


def _kind(action: object) -> str:
    """The kind of an ``action=`` value: its name, or its class's for an ``Action`` subclass."""
    return action if isinstance(action, str) else getattr(action, "__name__", str(action))

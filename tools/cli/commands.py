"""A command line's sub-commands, each declared once: name, help, arguments and handler.

::

    COMMANDS: Commands[Hand, []] = Commands()

    def _power_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("finger", help="0..3 or all")

    @COMMANDS.command("power", "switch finger power", _power_arguments)
    def _cmd_power(hand: Hand, args: argparse.Namespace) -> int:
        ...

:meth:`Commands.add_parsers` gives each its sub-parser, in the order they were declared (the
order ``--help`` lists them); :meth:`Commands.run` calls the one the command line chose with
what the program opened (a :class:`~host.hand.facade.Hand`, an :class:`~host.arm.facade.Arm`) and the
program's own extra arguments (``P``: armctl's output stream).  A command that opens no
robot (``armctl scan`` opens the bus itself) is declared with :meth:`Commands.alone` and run
with :meth:`Commands.run_alone`.  A check that needs no robot (a file that cannot be written)
runs first, with :meth:`Commands.check`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar

__all__ = ["Command", "Commands"]

#: What a command's handler drives (a Hand, an Arm).
T = TypeVar("T")
#: The program's extra arguments to every handler, after the parsed arguments.
P = ParamSpec("P")
#: Adds a sub-command's own arguments to its sub-parser.
Arguments = Callable[[argparse.ArgumentParser], object]
#: Refuses a command line before the link opens (raises the program's usage error).
Check = Callable[[argparse.Namespace], None]


@dataclass(frozen=True)
class Command(Generic[T, P]):
    """One sub-command: its name and help line, what adds its arguments, its handler (the
    exit status, from what it drives and the parsed arguments) or, for a command that opens
    no robot, its handler ``alone`` (from the parsed arguments), and an optional check made
    before anything is opened."""

    name: str
    help: str
    run: Callable[Concatenate[T, argparse.Namespace, P], int] | None
    alone: Callable[Concatenate[argparse.Namespace, P], int] | None = None
    arguments: Arguments | None = None
    check: Check | None = None

    @property
    def opens(self) -> bool:
        """True if the program opens its robot for this command."""
        return self.run is not None


class Commands(Generic[T, P]):
    """A program's sub-commands, in the order they were declared."""

    def __init__(self) -> None:
        self._by_name: dict[str, Command[T, P]] = {}

    def _declare(self, command: Command[T, P]) -> None:
        if command.name in self._by_name:
            raise ValueError(f"sub-command {command.name!r} is declared twice")
        self._by_name[command.name] = command

    def command(self, name: str, help: str, arguments: Arguments | None = None, *,
                check: Check | None = None
                ) -> Callable[[Callable[Concatenate[T, argparse.Namespace, P], int]],
                              Callable[Concatenate[T, argparse.Namespace, P], int]]:
        """Declare the decorated function as the handler of sub-command ``name``."""
        def declare(run: Callable[Concatenate[T, argparse.Namespace, P], int]
                    ) -> Callable[Concatenate[T, argparse.Namespace, P], int]:
            self._declare(Command(name, help, run, None, arguments, check))
            return run

        return declare

    def alone(self, name: str, help: str, arguments: Arguments | None = None, *,
              check: Check | None = None
              ) -> Callable[[Callable[Concatenate[argparse.Namespace, P], int]],
                            Callable[Concatenate[argparse.Namespace, P], int]]:
        """Declare the decorated function as the handler of sub-command ``name``, which
        opens no robot (it gets the parsed arguments and the extra ones only)."""
        def declare(run: Callable[Concatenate[argparse.Namespace, P], int]
                    ) -> Callable[Concatenate[argparse.Namespace, P], int]:
            self._declare(Command(name, help, None, run, arguments, check))
            return run

        return declare

    def add_parsers(self, sub: Any) -> None:
        """Give every sub-command its parser (``sub``: ``add_subparsers()``'s action)."""
        for c in self._by_name.values():
            parser = sub.add_parser(c.name, help=c.help)
            if c.arguments is not None:
                c.arguments(parser)

    def check(self, args: argparse.Namespace) -> None:
        """The chosen sub-command's check, before anything is opened."""
        chosen = self._by_name[args.command]
        if chosen.check is not None:
            chosen.check(args)

    def run(self, target: T, args: argparse.Namespace, *extra: P.args,
            **options: P.kwargs) -> int:
        """Run the chosen sub-command on ``target``; its exit status."""
        run = self._by_name[args.command].run
        assert run is not None, f"{args.command} opens no robot: run_alone"
        return run(target, args, *extra, **options)

    def run_alone(self, args: argparse.Namespace, *extra: P.args, **options: P.kwargs) -> int:
        """Run the chosen sub-command, one that opens no robot; its exit status."""
        alone = self._by_name[args.command].alone
        assert alone is not None, f"{args.command} needs its robot: run"
        return alone(args, *extra, **options)

    def __getitem__(self, name: str) -> Command[T, P]:
        return self._by_name[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self._by_name)

"""A click group that imports each subcommand's module on first use.

The "LazyGroup" pattern of click's documentation (Complex Applications, lazily
loading subcommands), plus one step further: the group's own ``--help`` lists
the commands from help lines given at registration instead of importing every
module for its docstring, which is what keeps ``bodymetry --help`` fast.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

import click

__all__ = ["LazyGroup"]


class LazyGroup(click.Group):
    """A :class:`click.Group` whose subcommands are imported when first needed.

    Parameters
    ----------
    lazy_subcommands : mapping
        Command name -> ``("package.module:attribute", help)``: where the
        :class:`click.Command` object lives, and the help text the group's
        command list shows for it (its first line, as in the command's docstring).
    *args, **kwargs
        As for :class:`click.Group`.
    """

    def __init__(
        self,
        *args: Any,
        lazy_subcommands: Mapping[str, tuple[str, str]] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_subcommands = dict(lazy_subcommands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy_subcommands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy_subcommands:
            return self.load(cmd_name)
        return super().get_command(ctx, cmd_name)

    def load(self, cmd_name: str) -> click.Command:
        """Import and return the command registered as ``cmd_name``."""
        target, _ = self.lazy_subcommands[cmd_name]
        module_name, _, attr = target.partition(":")
        command = getattr(importlib.import_module(module_name), attr)
        if not isinstance(command, click.Command):
            # A registration mistake, not a user error: fail loudly, naming it.
            raise TypeError(f"{target} (command {cmd_name!r}) is not a click command")
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list, from the registered help lines (imports nothing)."""
        names = self.list_commands(ctx)
        if not names:
            return
        limit = formatter.width - 6 - max(len(name) for name in names)
        rows = []
        for name in names:
            if name in self.lazy_subcommands:
                # A stand-in command shortens the text exactly as the real one would.
                stand_in = click.Command(name, help=self.lazy_subcommands[name][1])
                text = stand_in.get_short_help_str(limit)
            else:
                command = super().get_command(ctx, name)
                if command is None or command.hidden:
                    continue
                text = command.get_short_help_str(limit)
            rows.append((name, text))
        with formatter.section("Commands"):
            formatter.write_dl(rows)

"""What the commands' `--help` and shell completion share (click only, so that
`nmtcheck fleet` stays light): arguments described in a section of their own, and
LOG arguments completed as file names."""

from __future__ import annotations

from typing import Any

import click
from click.shell_completion import CompletionItem


class DocumentedCommand(click.Command):
    """A command whose `--help` describes its arguments in a section of their own,
    `arguments` ({name: text}), after the command's text (an argument's `help=` needs
    click 8.5; before it click lists none, 8.5 lists an undocumented one with no text)."""

    def __init__(self, *args: Any, arguments: dict[str, str] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.arguments = dict(arguments or {})

    def format_help_text(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        super().format_help_text(ctx, formatter)
        if self.arguments:
            with formatter.section("Arguments"):
                formatter.write_dl(list(self.arguments.items()))

    def format_arguments(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """Written by format_help_text (click 8.5 would add a section of its own)."""


def complete_paths(ctx: click.Context, param: click.Parameter, incomplete: str
                   ) -> list[CompletionItem]:
    """Shell completion of a LOG argument: the shell's own file names."""
    return [CompletionItem(incomplete, type="file")]


LOGS_HELP = ("Log files, directories (every log below them), quoted globs, URLs "
             "(s3://bucket/log.mf4) or - (standard input).")

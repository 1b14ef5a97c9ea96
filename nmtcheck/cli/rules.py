"""`nmtcheck rules`: the rule catalogue, or one rule's documentation (the docs site's rule
pages are generated from the same functions)."""

from __future__ import annotations

import re

import click

from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import Rule
from nmtcheck.cli.helptext import DocumentedCommand
from nmtcheck.errors import UsageError
from nmtcheck.settings.profiles import DEFAULT_PROFILE, Profile, load_profile


@click.command(name="rules", cls=DocumentedCommand,
               arguments={"CODE": "A rule code (H001) or name (heartbeat-timeout); without "
                                  "it, the catalogue."},
               short_help="List the rule catalogue, or document one rule.")
@click.argument("code", required=False)
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text",
              show_default=True)
def rules_cmd(code: str | None, fmt: str) -> None:
    """List the rule catalogue, or document one rule (CODE)."""
    defaults = load_profile(DEFAULT_PROFILE)
    if code is None:
        click.echo(rule_table(defaults) if fmt == "markdown" else "\n".join(
            f"{r.code}  {r.name:<28} {defaults[r.code].severity:<8} {r.summary}" for r in RULES))
        return
    r = BY_CODE.get(code.upper()) or next((x for x in RULES if x.name == code.lower()), None)
    if r is None:
        raise UsageError(f"rules: unknown rule code {code!r} (known: {', '.join(BY_CODE)})")
    doc = rule_doc(r, defaults)
    click.echo(f"{r.code} {r.name} (default severity: {defaults[r.code].severity})\n\n"
               + (doc if fmt == "markdown" else plain_text(doc)))


# The Markdown of the rules' docstrings: `**bold**`, `*emphasis*`, `` `code` ``
_MARKUP = re.compile(r"\*\*(?=\S)(.+?)(?<=\S)\*\*|(?<![\w*])\*(?=\S)([^*\n]+?)(?<=\S)\*(?![\w*])"
                     r"|`([^`\n]+)`")


def plain_text(markdown: str) -> str:
    """A rule's documentation as text for a terminal: its Markdown markup taken off
    (`nmtcheck rules CODE --format markdown` keeps it, as the docs site shows it)."""
    return _MARKUP.sub(lambda m: m[1] or m[2] or m[3], markdown)


def rule_doc(r: Rule, defaults: Profile) -> str:
    """A rule's documentation as `nmtcheck rules CODE` prints it after its title line (and
    the docs site's rule page shows it): the docstring, the parameters with their defaults."""
    lines = [r.doc]
    if r.params:
        lines += ["", "**Parameters** (rule profile `[rules." + r.code + "]`):"]
        for p in r.params:
            lines.append(f"- `{p.name}` = {defaults[r.code].params[p.name]!r}: {p.doc}")
    lines += ["", "Also: `enabled = false` turns it off; "
              "`severity = \"warning\"` changes its level."]
    return "\n".join(lines)


def rule_table(defaults: Profile) -> str:
    """The rule table of docs/reference/rules/index.md, generated from the registry."""
    rows = ["| code | name | severity | what it flags |", "|---|---|---|---|"]
    rows += [f"| {r.code} | {r.name} | {defaults[r.code].severity} | {r.summary} |"
             for r in RULES]
    return "\n".join(rows)

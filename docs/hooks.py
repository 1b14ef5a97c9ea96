"""MkDocs hook: one reference page per rule, generated from the rule registry.

Each page is what `nmtcheck rules CODE` prints (the rule's docstring, its parameters with
their defaults), so the docs cannot drift from the code. The pages are added to the build
and to the navigation under "Rules"; nothing is written to the source tree.
"""

from __future__ import annotations

from typing import Any

from mkdocs.structure.files import File, Files

from nmtcheck.checks import RULES
from nmtcheck.cli.rules import rule_doc
from nmtcheck.settings.profiles import load_profile

RULES_DIR = "reference/rules"
RULES_INDEX = f"{RULES_DIR}/index.md"


def _page(code: str) -> str:
    return f"{RULES_DIR}/{code}.md"


def on_config(config: Any) -> Any:
    """Put every rule's page under the nav entry of the rule index."""
    entries: list[Any] = [RULES_INDEX]
    entries += [{f"{r.code} {r.name}": _page(r.code)} for r in RULES]

    def walk(items: list[Any]) -> None:
        for i, item in enumerate(items):
            if isinstance(item, dict):
                for title, value in item.items():
                    if value == RULES_INDEX:
                        items[i] = {title: entries}
                    elif isinstance(value, list):
                        walk(value)

    walk(config["nav"] or [])
    return config


def on_files(files: Files, config: Any) -> Files:
    """Add reference/rules/CODE.md for every rule of the registry."""
    defaults = load_profile("default")
    for r in RULES:
        # Markdown needs a blank line before the parameter list that a terminal does not.
        doc = rule_doc(r, defaults).replace("]`):\n- ", "]`):\n\n- ", 1)
        text = (f"# {r.code} {r.name}\n\n"
                f"Default severity: **{defaults[r.code].severity}**. "
                f"`nmtcheck rules {r.code}` prints this page.\n\n" + doc + "\n")
        files.append(File.generated(config, _page(r.code), content=text))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Link each code of the generated rule table to its page."""
    if page.file.src_uri != RULES_INDEX:
        return markdown
    for r in RULES:
        markdown = markdown.replace(f"\n| {r.code} | ", f"\n| [{r.code}]({r.code}.md) | ", 1)
    return markdown

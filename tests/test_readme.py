"""The rule table of the docs (docs/reference/rules/index.md, linked from the README) is
generated from the registry, never kept by hand."""

from __future__ import annotations

from conftest import REPO

from nmtcheck.cli.main import rule_table
from nmtcheck.settings.profiles import load_profile

RULE_INDEX = REPO / "docs" / "reference" / "rules" / "index.md"


def test_readme_rule_table_is_generated() -> None:
    text = RULE_INDEX.read_text(encoding="utf-8")
    table = text.split("<!-- rules:start -->\n")[1].split("<!-- rules:end -->")[0].strip()
    assert table == rule_table(load_profile("default")).strip(), (
        f"regenerate the table in {RULE_INDEX.relative_to(REPO)} with: "
        "nmtcheck rules --format markdown")
    assert "docs/reference/rules/index.md" in (REPO / "README.md").read_text(encoding="utf-8")


def test_the_default_profile_is_what_the_rules_declare() -> None:
    """Severities and parameter defaults live in the rule declarations only."""
    from nmtcheck.checks import RULES

    profile = load_profile("default")
    assert set(profile) == {r.code for r in RULES}
    for r in RULES:
        assert profile[r.code].enabled
        assert profile[r.code].severity == r.severity
        assert profile[r.code].params == {p.name: p.default for p in r.params}


def test_every_rule_is_documented_as_the_catalogue_shows_it() -> None:
    """As ruff does through its metadata: every rule says what it checks, why it matters
    and gives an example, and every parameter has a meaning and a default of its type."""
    from nmtcheck.checks import RULES
    from nmtcheck.checks.base import SEVERITIES

    for r in RULES:
        assert r.severity in SEVERITIES, r.code
        assert r.summary and not r.summary.startswith("**"), r.code
        for section in ("**What it checks.**", "**Why it matters.**", "**Example.**"):
            assert section in r.doc, (r.code, section)
        for p in r.params:
            assert p.doc.strip(), (r.code, p.name)
            assert isinstance(p.default, p.type) and (  # a flag is a bool, nothing else is
                p.type is bool or not isinstance(p.default, bool)), (r.code, p.name)

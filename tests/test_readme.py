"""The README's rule table is generated from the registry, never kept by hand."""

from __future__ import annotations

from conftest import REPO

from nmtcheck.cli import rule_table
from nmtcheck.profiles import load_profile


def test_readme_rule_table_is_generated() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    table = text.split("<!-- rules:start -->\n")[1].split("<!-- rules:end -->")[0].strip()
    assert table == rule_table(load_profile("default")).strip(), (
        "regenerate with: nmtcheck rules --format markdown")


def test_default_profile_covers_every_rule_and_parameter() -> None:
    from nmtcheck.checks import RULES

    profile = load_profile("default")
    for r in RULES:
        assert profile[r.code].severity == r.severity
        assert set(profile[r.code].params) == {p.name for p in r.params}

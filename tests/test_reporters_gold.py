"""Every report format against a gold file, with versions and dates scrubbed.

Regenerate after an intended change with `NMTCHECK_UPDATE_GOLD=1 pytest
tests/test_reporters_gold.py` and review the diff like code.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from conftest import REPO

from nmtcheck import __version__
from nmtcheck.engine import check_input, select_rules
from nmtcheck.reporters import MODULES, renderer
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

GOLD = Path(__file__).resolve().parent / "gold"
SUFFIX = {"text": "txt", "concise": "concise.txt", "json": "json", "csv": "csv", "html": "html",
          "junit": "xml", "sarif": "sarif", "github": "github.txt", "markdown": "md"}
CASES = {
    "healthy": ["healthy"],  # no finding: every format's "all clear"
    "heartbeat_loss": ["heartbeat_loss"],  # one finding with an OFFLINE interval
    "all": ["healthy", "heartbeat_loss", "pdo_preop", "guard_toggle", "ignored_command",
            "reset_no_bootup"],  # several inputs, one finding of each kind
    # a candump log read as TRC (every record skipped: I001, I003 with channel and node
    # null) next to a normal one
    "input": ["heartbeat_loss:trc", "heartbeat_loss"],
}
DATE = re.compile(r"\d{4}-\d{2}-\d{2}[ T]\d{2}:\d{2}:\d{2}(?:\.\d+)?(?: UTC|Z)?")


def scrub(text: str) -> str:
    """Dates and the tool version change between runs and releases, not the report."""
    text = DATE.sub("<DATE>", text)
    return re.sub(rf"(?<![\d.]){re.escape(__version__)}(?![\d.])", "<VERSION>", text)


def _results(names: list[str], monkeypatch: pytest.MonkeyPatch) -> list[InputResult]:
    monkeypatch.chdir(REPO)  # relative paths, as a CI job in a checkout passes them
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    results = []
    for i, name in enumerate(names):
        name, _sep, input_format = name.partition(":")
        results.append(check_input(f"samples/{name}.log", i, profile, rules,
                                   input_format=input_format or None))
    return results


def test_every_format_has_a_gold_suffix() -> None:
    assert set(SUFFIX) == set(MODULES)


@pytest.mark.parametrize("fmt", sorted(SUFFIX))
@pytest.mark.parametrize("case", sorted(CASES))
def test_gold(case: str, fmt: str, monkeypatch: pytest.MonkeyPatch) -> None:
    results = _results(CASES[case], monkeypatch)
    options: dict[str, object] = {"fail_on": "error", "quiet": False,  # as the CLI passes them
                                  "config": {"file": None, "profile": "default",
                                             "overrides": []}}
    actual = scrub(renderer(fmt)(results, options))
    gold = GOLD / f"{case}.{SUFFIX[fmt]}"
    if os.environ.get("NMTCHECK_UPDATE_GOLD"):
        gold.parent.mkdir(exist_ok=True)
        gold.write_text(actual, encoding="utf-8")
    assert gold.exists(), f"no gold file {gold.name}: run with NMTCHECK_UPDATE_GOLD=1"
    expected = gold.read_text(encoding="utf-8")
    assert actual == expected, f"{gold.name} differs: NMTCHECK_UPDATE_GOLD=1 regenerates it"


def test_scrub_removes_dates_and_version_only() -> None:
    text = f"nmtcheck {__version__} generated 2026-01-02 03:04:05 UTC at 1.560400 s"
    assert scrub(text) == "nmtcheck <VERSION> generated <DATE> at 1.560400 s"

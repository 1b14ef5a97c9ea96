"""The SPEC 2026-11 cases (the NMT master, stale reports, period in force, H001 gaps, N002)
with what each must give, checked on nmtcheck itself.

These expectations were first written against the object-per-frame reference of afef50f
(tests/reference_model.py, retired with issue #14), which the package had to match; the
traces are in tests/snapshot_corpus.py and their whole outcome is in the snapshots too.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import Checker
from snapshot_corpus import SPEC_CASES, inputs, master_view, spec_trace, stale_indices, text_of

from nmtcheck.engine import check_input, select_rules
from nmtcheck.settings.profiles import load_profile

RULES = select_rules(load_profile("default"), [], [])


@pytest.mark.parametrize("name", sorted(SPEC_CASES))
def test_spec_2026_11_case(name: str, tmp_path: Path) -> None:
    _frames, want = SPEC_CASES[name]
    path, profile, net = inputs(spec_trace(name), tmp_path)
    res = check_input(path, 0, profile, RULES, net)
    cm = res.model.channels[0]
    if "master" in want:
        assert master_view(cm) == list(want["master"])
    if "stale" in want:
        assert sum(len(stale_indices(m)) for m in cm.nodes.values()) == want["stale"]
    for node, rules in want.get("rules_of", {}).items():
        assert [f.rule for f in res.findings if f.node == node] == rules
    if "rule" in want:
        assert want["rule"] in {f.rule for f in res.findings}
    if "no_rule" in want:
        assert want["no_rule"] not in {f.rule for f in res.findings}


def test_no_heartbeat_timeout_from_a_period_that_is_not_positive(checker: Checker) -> None:
    """Timestamps that go backwards make the measured period (median interval) negative.
    afef50f took `factor x period` < 0 as a timeout and raised H001 at every gap, and
    H002 for a heartbeat "-0.000 s after the previous one"; a period or timeout that is
    not positive now means "none". (Negative times in network and profile files, the
    other way to get one, are rejected when loading: test_cli.)"""
    res = checker.run(text_of([(0, "701#04"), (-1, "701#04")]))
    node = res.model.channels[0].nodes[1]
    assert node.period_s is not None and node.period_s < 0
    assert [f.rule for f in res.findings] == ["I005"]  # timestamps-backwards: the input's
    assert [iv.state for iv in node.intervals] == ["STOPPED"]

"""nmtcheck's outcome on a fixed corpus against recorded snapshots (tests/snapshots/).

The corpus (tests/snapshot_corpus.py) is rebuilt from fixed seeds at every run: 240
generated traces of 1-4 nodes plus the hand-written tricky traces, the SPEC 2026-11
cases, the healthy trace and the samples. For each, the findings of all rules of the
default profile (with the trace's network file and profile changes), every channel's
NMT master and every node's frame classes, stale reports, period, timeouts and state
intervals must be what the snapshot says. When recorded they agreed on every trace with
the object-per-frame reference of afef50f (tests/reference_model.py, retired with issue
#14), after one fix the comparison found (gen0175, see snapshot_corpus).

After an intended change (a new rule, a new SPEC reading) regenerate them with

    NMTCHECK_UPDATE_SNAPSHOTS=1 pytest tests/test_snapshots.py

and review the diff like code: `git diff --word-diff tests/snapshots/` shows which
findings and intervals moved.
"""

from __future__ import annotations

import difflib
import json
import os
from pathlib import Path

import pytest
from snapshot_corpus import GENERATED, Trace, corpus, generated, inputs, outcome

from nmtcheck.engine import check_input, select_rules
from nmtcheck.settings.profiles import load_profile

SNAPSHOTS = Path(__file__).resolve().parent / "snapshots"
UPDATE = bool(os.environ.get("NMTCHECK_UPDATE_SNAPSHOTS"))
CORPUS = corpus()
RULES = select_rules(load_profile("default"), [], [])


def _lines(trace: Trace, workdir: Path) -> list[str]:
    path, profile, net = inputs(trace, workdir)
    return outcome(trace, check_input(path, 0, profile, RULES, net))


def _by_log(lines: list[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in lines:
        out.setdefault(json.loads(line)["log"], []).append(line)
    return out


@pytest.mark.parametrize("stem", sorted(CORPUS))
def test_snapshot(stem: str, tmp_path: Path) -> None:
    snapshot = SNAPSHOTS / f"{stem}.jsonl"
    actual = {t.name: _lines(t, tmp_path) for t in CORPUS[stem]}
    if UPDATE:
        SNAPSHOTS.mkdir(exist_ok=True)
        snapshot.write_text("".join(f"{line}\n" for name in sorted(actual)
                                    for line in actual[name]), encoding="utf-8")
    assert snapshot.exists(), f"no {snapshot.name}: run with NMTCHECK_UPDATE_SNAPSHOTS=1"
    expected = _by_log(snapshot.read_text(encoding="utf-8").splitlines())
    assert sorted(actual) == sorted(expected), (
        f"{snapshot.name}: the corpus has other traces than the snapshot "
        f"(new: {sorted(set(actual) - set(expected))[:5]}, "
        f"gone: {sorted(set(expected) - set(actual))[:5]})")
    differ = [name for name in sorted(actual) if actual[name] != expected[name]]
    if differ:
        name = differ[0]
        trace = next(t for t in CORPUS[stem] if t.name == name)
        diff = "\n".join(difflib.unified_diff(
            _pretty(expected[name]), _pretty(actual[name]), "snapshot", "now", lineterm=""))
        shown = repr(trace).splitlines()
        if len(shown) > 60:
            shown = [*shown[:60], f"... ({len(shown) - 60} more lines: print(snapshot_corpus."
                                  f"trace_named({name!r}).text) in tests/)"]
        pytest.fail(f"{len(differ)} of {len(actual)} traces of {snapshot.name} differ "
                    f"({', '.join(differ[:8])}{', ...' if len(differ) > 8 else ''}); "
                    f"the first, {name}:\n{diff}\n\n" + "\n".join(shown) + "\n"
                    "If the change is intended: NMTCHECK_UPDATE_SNAPSHOTS=1 pytest "
                    "tests/test_snapshots.py, and review the diff.")


def _pretty(lines: list[str]) -> list[str]:
    """One finding, master or node per line, and a node's intervals one per line, so
    that the diff points at what moved."""
    out = []
    for line in lines:
        rec = json.loads(line)
        rec.pop("log")
        intervals = rec.pop("intervals", None)
        out.append(json.dumps(rec, ensure_ascii=False))
        out += [f"    {iv}" for iv in intervals or ()]
    return out


def test_the_generated_corpus_is_fixed_and_varied() -> None:
    """The generator is fixed: the same seed gives the same trace (the snapshot headers
    hold each input's digest; this is a quick check of the generator alone)."""
    assert generated(7).digest() == generated(7).digest()
    assert len({t.digest() for t in CORPUS["generated"]}) == GENERATED
    tags = {tag for t in CORPUS["generated"] for tag in t.tags}
    for kind in ("bootup", "bootup_1017", "twins_out_of_phase", "twins_stalled_producer",
                 "guard_late", "guard_stuck", "guard_none", "mixed", "odd_dlc", "odd_code",
                 "sdo_1016_60", "sdo_1017_80", "tpdo", "silence", "heartbeat_same",
                 "master_startups_1", "master_startups_2", "master_obeys_yes",
                 "master_obeys_late", "master_reset_before", "command_at_before",
                 "command_at_bootup", "command_broadcast", "command_direct", "two_buses",
                 "network_file", "network_master", "profile_params"):
        assert kind in tags, kind

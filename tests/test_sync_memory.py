"""What a SYNC costs: a log of 5 M SYNCs at 1 kHz took 757 MB (the SYNC channel's columns
copied from the decoded ones, Y001 and Y002 working on arrays of every SYNC at once, in
int64), 460 MB since (2-core VM, 2026-12-08, docs/status.md). The findings and reports
must not change: Y001 judges a window of SYNCs at a time, with the window's last SYNC
seeing the next window's first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_many_inputs import GROUPS, _check, _reports

from nmtcheck.checks import base as rules_base
from nmtcheck.processes import sync as sync_stage
from nmtcheck.settings.network import load_network

WITH_SYNC = sorted(g for g, (_logs, net) in GROUPS.items()
                   if net is not None and "sync" in net.read_text().lower())


def _sync_log(path: Path) -> Path:
    """A 10 ms SYNC with a counter (C = 8) to node 2, OPERATIONAL with heartbeats; SYNCs
    missing at 1.0 s, 1.03 s and 2.5 s (three Y001 gaps, some at the edges of a window of
    3 SYNCs), a counter skipped (Y003) and a DLC 2 SYNC (Y002)."""
    lines = ["(0.000000) can0 702#00", "(0.001000) can0 000#0100"]
    lines += [f"({0.05 + 0.1 * k:.6f}) can0 702#05" for k in range(30)]
    counter = 0
    for k in range(300):
        t = 0.01 + 0.01 * k
        if round(t, 6) in (1.0, 1.03, 1.04, 2.5):
            continue
        counter = counter % 8 + 1 + (1 if k == 150 else 0)
        counter = (counter - 1) % 8 + 1
        data = f"{counter:02X}" + ("00" if k == 200 else "")
        lines.append(f"({t:.6f}) can0 080#{data}")
    lines.sort(key=lambda line: float(line[1:line.index(")")]))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_y001_judges_windows_as_it_judged_the_whole(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Windows of 1, 2 and 3 SYNCs give the findings and reports of one window."""
    log = _sync_log(tmp_path / "sync.log")
    net_path = tmp_path / "network.toml"
    net_path.write_text("[sync]\nperiod_us = 10000\ncounter_overflow = 8\n"
                        "[nodes.2]\nheartbeat_ms = 100\n")
    network = load_network(str(net_path))
    whole = _check([log], network)
    rules = sorted(f.rule for f in whole[0].findings if f.rule.startswith("Y"))
    assert rules.count("Y001") == 3 and "Y002" in rules and "Y003" in rules, rules
    for window in (1, 2, 3):
        monkeypatch.setattr(rules_base, "WINDOW", window)
        got = _check([log], network)
        assert [(f.rule, f.time, f.message) for f in got[0].findings] == [
            (f.rule, f.time, f.message) for f in whole[0].findings]
        assert _reports(got) == _reports(whole)


def test_sample_groups_with_sync_are_compared() -> None:
    assert len(WITH_SYNC) >= 5, WITH_SYNC


@pytest.mark.parametrize("group", WITH_SYNC)
def test_the_real_stacks_sync_reports_the_same_in_windows(
        group: str, monkeypatch: pytest.MonkeyPatch) -> None:
    logs, net_path = GROUPS[group]
    assert net_path is not None
    network = load_network(str(net_path))
    whole = _reports(_check(logs, network))
    monkeypatch.setattr(rules_base, "WINDOW", 2)
    assert _reports(_check(logs, network)) == whole


def test_one_channels_sync_columns_are_the_decoded_ones(tmp_path: Path) -> None:
    """Every SYNC of the input on one channel: the SYNC channel holds the decoded columns
    themselves (no copy); on two channels, each its own rows."""
    log = _sync_log(tmp_path / "sync.log")
    (res,) = _check([log], None)
    sc = sync_stage.of(res.model).channels["can0"]  # type: ignore[union-attr]
    decoded = res.model.decoded.sync
    assert len(sc) == len(decoded["ts"]) > 0
    assert np.shares_memory(sc.ts, decoded["ts"]) and np.shares_memory(sc.line,
                                                                       decoded["line"])
    two = tmp_path / "two.log"
    text = log.read_text()
    two.write_text(text + text.replace("can0", "can1"))
    (res2,) = _check([two], None)
    analysis = sync_stage.of(res2.model)
    assert analysis is not None
    a, b = analysis.channels["can0"], analysis.channels["can1"]
    assert len(a) == len(b) == len(sc)
    assert not np.shares_memory(a.ts, res2.model.decoded.sync["ts"])
    assert np.array_equal(a.ts, sc.ts) and np.array_equal(a.counter, b.counter)

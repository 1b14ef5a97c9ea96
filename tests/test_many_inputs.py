"""Many inputs in one check: each result keeps only what the reports read
(results.for_reports), and every report is the same byte for byte as from the whole result.

`nmtcheck check DIR` holds every input's result until the reports are written at the end;
a directory of 100,000 two-line logs reached 2.5 GB (bench/PATHOLOGICAL.md, "A directory
of many two-line logs"). The reports must not change for it: each sample recording below is
checked twice, once kept whole and once for the reports (in this process, and sent back
from a worker process as `-j` does), and all nine formats are compared.
"""

from __future__ import annotations

import gc
import pickle
import re
import subprocess
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import SAMPLES

from nmtcheck.engine import check_input, check_inputs, select_rules
from nmtcheck.reporters import MODULES, renderer, statistics_renderer, streamer
from nmtcheck.results import RELEASED, InputResult, PackedResult, for_reports
from nmtcheck.settings.network import Network, load_network
from nmtcheck.settings.profiles import load_profile
from nmtcheck.timeline import tables

TWO_LINES = "(1.000000) can0 701#00\n(1.100000) can0 701#05\n"  # boot-up, OPERATIONAL
# the moments a report is written and the run's random SARIF GUID change between renders
VARYING = re.compile(r"\d{4}-\d{2}-\d{2}[ T]\d{2}:\d{2}:\d{2}(?:\.\d+)?(?: UTC|Z)?|"
                     r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}")


def _groups() -> dict[str, tuple[list[Path], Path | None]]:
    """The sample recordings of the real stacks (and the generated ones), each with the
    network file its folder gives it (`network_<name>.toml`, else `network.toml`), grouped
    by folder and network: one multi-input check each."""
    out: dict[str, tuple[list[Path], Path | None]] = {}
    for log in sorted(SAMPLES.rglob("*.log")):
        own = log.with_name(f"network_{log.stem}.toml")
        net = own if own.is_file() else log.with_name("network.toml")
        net_or_none = net if net.is_file() else None
        key = str((net_or_none or log).relative_to(SAMPLES).with_suffix(""))
        if net_or_none is None:
            key = str(log.parent.relative_to(SAMPLES)) or "samples"
        out.setdefault(key, ([], net_or_none))[0].append(log)
    out["samples without a network file"] = (sorted(SAMPLES.glob("*.log")), None)
    return out


GROUPS = _groups()


def _check(logs: list[Path], network: Network | None, jobs: int = 1,
           reports_only: bool = False) -> list[InputResult]:
    profile = load_profile("default")
    return check_inputs([str(p) for p in logs], jobs, profile, select_rules(profile, [], []),
                        keep_going=True, reports_only=reports_only, network=network)


def _reports(results: list[InputResult]) -> dict[str, str]:
    """Every format as the CLI writes it (its streamed pieces, with and without -q) and
    --statistics, dates and GUIDs blanked."""
    out = {}
    for quiet in (False, True):
        options: dict[str, object] = {"fail_on": "error", "quiet": quiet, "max_findings": 10000,
                                      "config": {"file": None, "profile": "default",
                                                 "overrides": []}}
        for fmt in MODULES:
            text = "".join(streamer(fmt)(results, options))
            out[f"{fmt} quiet={quiet}"] = VARYING.sub("<X>", text)
            if not quiet:
                assert VARYING.sub("<X>", renderer(fmt)(results, options)) == out[
                    f"{fmt} quiet={quiet}"]
        out[f"statistics quiet={quiet}"] = statistics_renderer("text")(results, options)
    return out


@pytest.mark.parametrize("group", sorted(GROUPS))
def test_reports_of_results_kept_for_the_reports_are_the_same(group: str) -> None:
    logs, net_path = GROUPS[group]
    network = load_network(str(net_path)) if net_path is not None else None
    whole = _reports(_check(logs, network))
    kept = _check(logs, network, reports_only=True)
    assert all(vars(res.model)["decoded"] is RELEASED for res in kept if res.error is None)
    assert _reports(kept) == whole
    # as a worker process sends each result back (-j): packed, then unpacked here
    sent = [PackedResult.of(res).unpack() for res in _check(logs, network)]
    assert _reports(sent) == whole


def test_every_sample_folder_is_compared() -> None:
    """The comparison covers the real stacks' recordings with their network files."""
    compared = {log for logs, _net in GROUPS.values() for log in logs}
    assert compared == set(SAMPLES.rglob("*.log"))
    assert {"lely", "canopennode", "canopen_master"} <= {
        g.split("/")[0] for g in GROUPS}
    assert sum(net is not None for _logs, net in GROUPS.values()) >= 20


def test_worker_processes_give_the_same_reports(tmp_path: Path) -> None:
    """-j 2 with results kept for the reports: the same reports as one process keeping
    them whole."""
    logs, net_path = GROUPS["lely/comm/network_sync_pdo"]
    network = load_network(str(net_path)) if net_path is not None else None
    unreadable = tmp_path / "missing.log"  # an input error among them: a result of its own
    many = [*logs, *GROUPS["canopennode/network"][0][:4], unreadable]
    assert _reports(_check(many, network, jobs=2, reports_only=True)) == _reports(
        _check(many, network))


def test_worker_results_tell_the_progress_bar_their_frames(tmp_path: Path) -> None:
    """With -j, each input's frames reach the progress display once its result is back."""

    class Recorder:
        def __init__(self) -> None:
            self.started: list[str] = []
            self.counted = 0

        def start_input(self, path: str) -> None:
            self.started.append(path)

        def frames(self, n: int) -> None:
            self.counted += n

    paths = _two_line_logs(tmp_path, 3)
    profile = load_profile("default")
    seen = Recorder()
    check_inputs(paths, 2, profile, select_rules(profile, [], []), progress=seen,
                 reports_only=True)
    assert sorted(seen.started) == paths
    assert seen.counted == 6


def _two_line_logs(directory: Path, count: int) -> list[str]:
    paths = []
    for i in range(count):
        path = directory / f"log{i:05d}.log"
        path.write_text(TWO_LINES)
        paths.append(str(path))
    return paths


def _kept_per_input(paths: list[str], **kw: object) -> float:
    """Bytes that the results of `paths` hold after the check (tracemalloc)."""
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    check_inputs(paths[:2], 1, profile, rules)  # the modules' caches, before tracing
    gc.collect()
    tracemalloc.start()
    try:
        results = check_inputs(paths, 1, profile, rules, **kw)  # type: ignore[arg-type]
        gc.collect()
        kept = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(results) == len(paths)
    return kept / len(paths)


def test_a_two_line_log_keeps_half_of_what_it_did(tmp_path: Path) -> None:
    """Its decoded frames (spooled columns, per-frame views) were half of what each
    result held until the reports were written: 21 KB per two-line log, 11 KB without
    them (2026-12-08, Python 3.11)."""
    paths = _two_line_logs(tmp_path, 300)
    whole = _kept_per_input(paths)
    kept = _kept_per_input(paths, reports_only=True)
    assert kept < 0.6 * whole, (kept, whole)


def test_a_result_sent_back_shares_what_every_result_repeats(tmp_path: Path) -> None:
    """Unpacked, two results hold one zero-length array per dtype and shape, the
    timeline's one shared empty table, and one copy of each short string they repeat;
    a plain pickle gave each result its own (a two-line log's result took 32 KB there,
    11 KB in the process that checked it)."""
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    a, b = (PackedResult.of(check_input(p, i, profile, rules)).unpack()
            for i, p in enumerate(_two_line_logs(tmp_path, 2)))
    ma, mb = a.nodes()[0], b.nodes()[0]
    assert ma.commands is mb.commands is tables._SHARED[type(ma.commands)]
    assert ma.writes is mb.writes is tables._SHARED[type(ma.writes)]
    assert not len(ma.own_command_idx) and ma.own_command_idx is mb.own_command_idx
    assert not ma.own_command_idx.flags.writeable
    assert ma.channel is mb.channel == "can0"
    assert set(a.not_evaluated) == set(b.not_evaluated) != set()
    assert all(a.not_evaluated[c] is b.not_evaluated[c] for c in a.not_evaluated)
    assert a.stats.path != b.stats.path
    assert vars(a.model)["decoded"] is vars(b.model)["decoded"] is RELEASED


def test_the_released_frames_say_so() -> None:
    """A use of the decoded frames after the check fails naming why, never reads empty
    tables; pickling and repr still work."""
    with pytest.raises(AttributeError, match="released once its result is kept for the "
                                             "reports"):
        _ = RELEASED.node_frames
    assert not hasattr(RELEASED, "ec")
    assert pickle.loads(pickle.dumps(RELEASED)) is RELEASED
    assert "released" in repr(RELEASED)


def test_for_reports_keeps_the_findings_and_the_nodes() -> None:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    path = str(SAMPLES / "heartbeat_loss.log")
    whole = check_input(path, 0, profile, rules)
    kept = for_reports(check_input(path, 0, profile, rules))
    assert [f.rule for f in kept.findings] == [f.rule for f in whole.findings] != []
    assert [(m.channel, m.node) for m in kept.nodes()] == [
        (m.channel, m.node) for m in whole.nodes()]
    for mk, mw in zip(kept.nodes(), whole.nodes(), strict=True):
        assert np.array_equal(mk.intervals.state, mw.intervals.state)


def test_check_keeps_each_result_for_the_reports(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """`nmtcheck check` hands the reports results kept for them; the Python API, whose
    `Report.results` gives the model, keeps them whole."""
    from click.testing import CliRunner

    from nmtcheck import api
    from nmtcheck.cli import check as check_command
    from nmtcheck.cli.common import write_reports
    from nmtcheck.timeline.decode import Decoded

    seen: list[InputResult] = []

    def spy(results: list[InputResult], *args: Any) -> None:
        seen.extend(results)
        write_reports(results, *args)

    monkeypatch.setattr(check_command, "write_reports", spy)
    paths = _two_line_logs(tmp_path, 3)
    ran = CliRunner().invoke(check_command.check, ["--isolated", str(tmp_path), "-q",
                                                   "--fail-on", "never"])
    assert ran.exit_code == 0, ran.output
    assert len(seen) == 3
    assert all(vars(res.model)["decoded"] is RELEASED for res in seen)
    report = api.check(paths)
    assert all(isinstance(res.model.decoded, Decoded) for res in report.results)


POOL_RUN = """
from nmtcheck.fleet.executors import ResilientPool
pool = ResilientPool(2)
for i in range(6000):
    pool.submit(i, abs, -i)
got = {}
while len(got) < 6000:
    got.update(pool.done())
pool.close()
assert got == {i: i for i in range(6000)}, len(got)
print("ok")
"""


def test_the_worker_pool_runs_thousands_of_inputs() -> None:
    """Each task tells the pool it started (to know the suspects when a worker dies);
    unread, those notes filled their pipe after some 2,700 tasks and every worker
    blocked: `check -j 2` on a directory of 20,000 logs hung (2026-12-08)."""
    ran = subprocess.run([sys.executable, "-c", POOL_RUN], capture_output=True, text=True,
                         timeout=300, check=False)
    assert ran.returncode == 0 and ran.stdout.strip() == "ok", ran.stderr[-2000:]

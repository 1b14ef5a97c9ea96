"""Long logs keep steady heartbeat runs as summaries (`ec_compact`, issue 24): every
report is the same as without them.

The compaction starts above 2 M error-control rows; here it is forced on small logs
(`SETTINGS.above = 0`, small chunks) and each report is compared with the uncompacted
check of the same log: every recorded sample (with and without its network file), and
generated logs where a steady run crosses a rule's limit, so that the node must be read
back whole.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO

from nmtcheck.engine import check_input, select_rules
from nmtcheck.fleet.tasks import node_rows
from nmtcheck.readers.frames import node_key
from nmtcheck.reporters import renderer
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile
from nmtcheck.spool import ColumnSpool
from nmtcheck.timeline import ec_compact
from nmtcheck.timeline.gaps import Gaps

FORCED = ec_compact.Compaction(above=0, chunk=53, margin=8, protect_s=1.0, min_run=1)
TIGHT = ec_compact.Compaction(above=0, chunk=31, margin=4, protect_s=0.0, min_run=1)
OPTIONS: dict[str, object] = {"fail_on": "error", "quiet": False,
                              "config": {"file": None, "profile": "default", "overrides": []}}
# when a report was made: ISO in JSON and text, "2026-11-26 22:26:30 UTC" in HTML
DATE = re.compile(r"\d{4}-\d\d-\d\d(T[0-9:.]+(Z|[+-]\d\d:\d\d)?| \d\d:\d\d:\d\d UTC)")


@pytest.fixture
def settings(monkeypatch: pytest.MonkeyPatch) -> Iterator[pytest.MonkeyPatch]:
    """Restores the default settings after a test that changes them."""
    monkeypatch.setattr(ec_compact, "SETTINGS", ec_compact.Compaction())
    yield monkeypatch


def _check(path: Path, network: Path | None, compaction: ec_compact.Compaction,
           mp: pytest.MonkeyPatch) -> InputResult:
    mp.setattr(ec_compact, "SETTINGS", compaction)
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []),
                       network=load_network(str(network)) if network else None)


def _reports(res: InputResult) -> dict[str, str]:
    return {fmt: DATE.sub("<DATE>", renderer(fmt)([res], OPTIONS)) for fmt in ("json", "text")}


def _dropped(res: InputResult) -> int:
    return sum(r.dropped for r in res.model.decoded.ec_runs.values())


# -- the multiset ---------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(20))
def test_counted_statistics_equal_numpy_on_the_expanded_values(seed: int) -> None:
    rng = np.random.default_rng(seed)
    plain = rng.choice([0.1, 0.1000002, 0.0999998, 0.2, 0.05], size=rng.integers(0, 30))
    hists = []
    for _ in range(rng.integers(1, 4)):
        vals = np.unique(rng.normal(0.1, 0.003, rng.integers(1, 9)))
        hists.append((vals, rng.integers(1, 500, len(vals))))
    gaps = Gaps.join(plain, hists)
    expanded = np.concatenate([plain, *(np.repeat(v, c) for v, c in hists)])
    assert gaps.count == len(expanded)
    assert gaps.minimum() == expanded.min() and gaps.maximum() == expanded.max()
    assert gaps.median() == np.median(expanded)
    for q in (50, 95, 0, 100, 37.5):
        assert gaps.percentile(q) == np.percentile(expanded, q)
    assert gaps.std() == pytest.approx(np.std(expanded), rel=1e-9, abs=1e-15)


def test_plain_intervals_are_numpys_own() -> None:
    values = np.asarray([0.3, 0.1, 0.2, 0.1])
    gaps = Gaps(values)
    assert (gaps.median(), gaps.percentile(95), gaps.std()) == (
        np.median(values), np.percentile(values, 95), np.std(values))


# -- every recorded sample ------------------------------------------------------------------

def _samples() -> list[tuple[Path, Path | None]]:
    cases: list[tuple[Path, Path | None]] = []
    for log in sorted((REPO / "samples").rglob("*.log")):
        cases.append((log, None))
        net = log.parent / "network.toml"
        if net.exists():
            cases.append((log, net))
    return cases


def test_every_sample_report_is_the_same_compacted(settings: pytest.MonkeyPatch) -> None:
    dropped = 0
    for log, net in _samples():
        whole = _reports(_check(log, net, ec_compact.Compaction(), settings))
        for compaction in (FORCED, TIGHT):
            res = _check(log, net, compaction, settings)
            dropped += _dropped(res)
            assert _reports(res) == whole, (log, net, compaction)
    assert dropped > 5000  # the comparison compared something: runs were dropped


# -- generated long logs --------------------------------------------------------------------

def _write(path: Path, frames: list[tuple[float, int, str]]) -> Path:
    frames.sort()
    path.write_text("".join(f"({1_700_000_000 + t:.6f}) can0 {cid:03X}#{data}\n"
                            for t, cid, data in frames))
    return path


def _heartbeats(node: int, t0: float, t1: float, period: float, jitter: float = 0.0,
                seed: int = 0, state: str = "05") -> list[tuple[float, int, str]]:
    rng = np.random.default_rng(seed + node)
    n = int((t1 - t0) / period)
    ts = t0 + np.arange(n) * period + rng.uniform(-jitter, jitter, n)
    return [(round(float(t), 6), 0x700 + node, state) for t in ts]


def _spy_restore(mp: pytest.MonkeyPatch) -> list[set[int]]:
    """The node keys each `ec_compact.restore` call reads back, in order."""
    restored: list[set[int]] = []
    real_restore = ec_compact.restore

    def spy(spool: ColumnSpool, cols: dict[str, np.ndarray], runs: dict[int, ec_compact.GapRuns],
            guard: dict[int, ec_compact.GuardRuns], keys: set[int], chunk: int
            ) -> tuple[dict[str, np.ndarray], dict[int, ec_compact.GapRuns],
                       dict[int, ec_compact.GuardRuns]]:
        restored.append(set(keys))
        return real_restore(spool, cols, runs, guard, keys, chunk)

    mp.setattr(ec_compact, "restore", spy)
    return restored


def _network(path: Path, nodes: dict[int, int]) -> Path:
    path.write_text("".join(f"[nodes.{n}]\nheartbeat_ms = {ms}\n\n" for n, ms in nodes.items()))
    return path


def test_a_long_steady_log_keeps_a_few_rows_and_the_same_report(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    frames = [(0.0, 0x700 + n, "00") for n in (2, 3, 4)]
    for n in (2, 3, 4):
        frames += _heartbeats(n, 0.01 * n, 60.0, 0.1, jitter=0.002, seed=n)
    frames = [f for f in frames if not (f[1] == 0x703 and 30.0 < f[0] < 30.5)]  # lost
    frames = [(t, c, "04" if c == 0x704 and t > 45.0 else d) for t, c, d in frames]
    frames += [(45.0, 0x000, "0204")]  # stop node 4: its next heartbeats say 04h
    log = _write(tmp_path / "steady.log", frames)
    whole = _check(log, None, ec_compact.Compaction(), settings)
    # the defaults but for the threshold: runs shorter than 32 frames are kept
    default = _check(log, None, ec_compact.Compaction(above=0), settings)
    assert _reports(default) == _reports(whole)
    runs = default.model.decoded.ec_runs
    assert runs and all(bool((r.n >= 32).all()) for r in runs.values())
    assert len(default.model.decoded.ec["ts"]) < len(frames) / 10
    res = _check(log, None, FORCED, settings)
    assert _reports(res) == _reports(whole)
    assert [f.rule for f in res.findings] == ["H001"]
    rows = len(res.model.decoded.ec["ts"])
    assert rows < len(frames) / 5  # most rows are dropped, with their intervals counted
    for m, w in zip(res.model.nodes(), whole.model.nodes(), strict=True):
        assert m.ec.count(2) == w.ec.count(2)  # heartbeats, the dropped ones included
    key = {"input_id": "x"}
    assert node_rows(res, key, "d", {}) == node_rows(whole, key, "d", {})
    html = renderer("html")
    assert DATE.sub("", html([res], OPTIONS)) == DATE.sub("", html([whole], OPTIONS))


def test_jittered_heartbeats_compact_to_a_few_rows_whatever_the_length(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    """Real heartbeats jitter: 10 ms +-0.5 ms puts intervals 10 % off the median, and every
    such run must still be dropped (issue 39: with runs only of intervals within 5 % of
    the median, a jittered 20 M-frame log kept nearly every row and took 1.5 GB)."""
    kept = []
    for seconds in (30.0, 90.0):
        frames = [(0.0, 0x700 + n, "00") for n in range(1, 5)]
        for n in range(1, 5):
            frames += _heartbeats(n, 0.001 * n, seconds, 0.01, jitter=0.0005, seed=7)
        log = _write(tmp_path / f"jitter-{seconds:.0f}.log", frames)
        whole = _check(log, None, ec_compact.Compaction(), settings)
        res = _check(log, None, ec_compact.Compaction(above=0), settings)
        assert _reports(res) == _reports(whole)
        assert res.findings == [] or {f.rule for f in res.findings} <= {"B002"}
        assert _dropped(res) > 0.99 * len(frames) - 400
        kept.append(len(res.model.decoded.ec["ts"]))
    assert kept[1] <= kept[0] + 16  # three times the frames, the same few rows
    assert kept[0] < 700  # the first second after the boot-ups stays whole


@pytest.mark.parametrize("period, rules", [
    (0.12, ["H003"]),  # steady 20 % slower than 1017h: every run leaves the tolerance
    (0.16, ["H001"]),  # steady beyond the timeout: a finding per gap
    (0.04, ["H002"]),  # steady far too early
])
def test_a_run_a_limit_cuts_is_read_back_whole(
        tmp_path: Path, settings: pytest.MonkeyPatch, period: float, rules: list[str]) -> None:
    frames = [(0.0, 0x702, "00"), (0.0, 0x703, "00")]
    frames += _heartbeats(2, 0.01, 20.0, 0.1, jitter=0.001)
    frames += _heartbeats(3, 0.02, 20.0, period, jitter=0.0005)
    log = _write(tmp_path / "slow.log", frames)
    net = _network(tmp_path / "network.toml", {2: 100, 3: 100})
    whole = _check(log, net, ec_compact.Compaction(), settings)
    restored = _spy_restore(settings)
    res = _check(log, net, FORCED, settings)
    assert restored == [{3}]  # node 3 was compacted, then read back whole
    assert _reports(res) == _reports(whole)
    assert set(rules) <= {f.rule for f in res.findings}
    assert {f.node for f in res.findings} == {3}
    runs = res.model.decoded.ec_runs  # keys: channel code 0, so the node-IDs
    assert 3 not in runs and 2 in runs  # node 3 read back whole, node 2 still compacted


def test_a_short_log_is_not_compacted_by_default(settings: pytest.MonkeyPatch) -> None:
    res = _check(REPO / "samples" / "lely" / "healthy.log", None, ec_compact.Compaction(),
                 settings)
    assert res.model.decoded.ec_runs == {} and res.model.decoded.ec_spool is None


def test_two_channels_and_a_timeless_log_give_the_same_reports(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    lines = []
    for chan in ("can0", "can1"):
        frames = [(0.0, 0x702, "00")] + _heartbeats(2, 0.01, 30.0, 0.1, jitter=0.001)
        if chan == "can1":  # reset node 2 on can1 only: its boot-up answers
            frames += [(15.0, 0x000, "8102"), (15.2, 0x702, "00")]
        lines += [(t, chan, c, d) for t, c, d in frames]
    lines.sort()
    two = tmp_path / "two.log"
    two.write_text("".join(f"({1_700_000_000 + t:.6f}) {ch} {c:03X}#{d}\n"
                           for t, ch, c, d in lines))
    timeless = tmp_path / "timeless.log"  # pasted without timestamps: file order only
    timeless.write_text("".join(f"{ch} {c:03X}#{d}\n" for _t, ch, c, d in lines))
    for log in (two, timeless):
        whole = _check(log, None, ec_compact.Compaction(), settings)
        res = _check(log, None, FORCED, settings)
        assert _reports(res) == _reports(whole), log.name
    assert _dropped(_check(two, None, FORCED, settings)) > 400


def test_timestamps_that_go_backwards_give_the_same_report(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    frames = [(0.0, 0x702, "00"), (0.0, 0x703, "00")] + _heartbeats(
        2, 0.01, 20.0, 0.1, jitter=0.001) + _heartbeats(3, 0.02, 20.0, 0.1, jitter=0.001)
    frames += [(10.0, 0x000, "8103"), (10.1, 0x703, "00")]  # node 3 reset, boots
    log = _write(tmp_path / "back.log", frames)
    lines = log.read_text().splitlines(keepends=True)
    # frames out of place: the reset and node 3's boot-up written 60 frames late, and one
    # heartbeat early: time goes back (I005), bounds fall between runs of one span
    moved = [ln for ln in lines if "#8103" in ln or " 703#00" in ln][1:]
    lines = [ln for ln in lines if ln not in moved]
    at = next(i for i, ln in enumerate(lines) if float(ln[1:ln.index(")")]) > 1_700_000_010.2)
    lines[at + 60:at + 60] = moved
    lines.insert(100, lines[150])
    log.write_text("".join(lines))
    whole = _check(log, None, ec_compact.Compaction(), settings)
    res = _check(log, None, FORCED, settings)
    assert "I005" in {f.rule for f in res.findings}
    assert _dropped(res) > 100 and _reports(res) == _reports(whole)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_temporary_disk_is_one_line_naming_tmpdir() -> None:
    from nmtcheck.errors import NmtcheckError
    from nmtcheck.spool import write_spill

    with open("/dev/full", "ab") as f, pytest.raises(NmtcheckError, match="set TMPDIR"):
        write_spill(np.zeros(1 << 16), f, "/tmp/nmtcheck-x")


def test_short_runs_are_kept() -> None:
    drop = np.asarray([0, 1, 1, 0, 1, 1, 1, 1, 0, 1], bool)
    ec_compact._keep_short_runs(drop, 3)
    assert drop.astype(int).tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 0, 0]


def test_a_nodes_tail_between_chunks_holds_its_own_rows_not_the_chunks() -> None:
    """The rows a node hands the next chunk are copies: a view kept the node's rows of the
    whole chunk alive, and a BLF whose 64 containers restart their times (a capture and
    so a node key each, ending in turn) took 661 MB for 22.4 M heartbeats, 196 MB after
    (issue 39)."""
    n = 100_000
    rows = {"key": np.ones(n, np.int64), "idx": np.arange(n, dtype=np.int64),
            "ts": np.arange(n) * 0.01, "rtr": np.zeros(n, bool),
            "dlc": np.ones(n, np.uint8), "value": np.full(n, 0x05, np.uint8)}
    node = ec_compact._Node()
    ec_compact._chunk(node, rows, None, 1, ec_compact.Compaction(), final=False)
    assert node.tail is not None
    held = sum(col.base.nbytes if col.base is not None else col.nbytes
               for col in node.tail.values())
    held += node.tail_odd.nbytes if node.tail_odd.base is None else node.tail_odd.base.nbytes
    assert len(node.tail["ts"]) <= 2 * ec_compact.Compaction().margin + 2 + 16
    assert held < 4096


# -- node guarding ----------------------------------------------------------------------------

def _guarded(node: int, t0: float, t1: float, period: float, latency: float = 0.002,
             jitter: float = 0.0, seed: int = 0, state: int = 0x05
             ) -> list[tuple[float, int, str]]:
    """The master's remote request to `node` every `period`, each answered `latency`
    later with `state` and the toggle bit alternating from 0."""
    rng = np.random.default_rng(seed + node)
    n = int((t1 - t0) / period)
    ts = t0 + np.arange(n) * period + rng.uniform(-jitter, jitter, n)
    out = []
    for i, t in enumerate(ts.tolist()):
        out.append((round(t, 6), 0x700 + node, "R"))
        out.append((round(t + latency, 6), 0x700 + node, f"{(i % 2) << 7 | state:02X}"))
    return out


def _guard_dropped(res: InputResult) -> int:
    return sum(r.dropped for r in res.model.decoded.ec_guard_runs.values())


def test_a_long_guarded_log_keeps_a_few_rows_and_the_same_report(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    frames = _guarded(2, 0.011, 60.0, 0.1, jitter=0.002, seed=2)
    frames += _guarded(3, 0.023, 60.0, 0.1, latency=0.004, jitter=0.001, seed=3)
    frames += _heartbeats(4, 0.05, 60.0, 0.1, jitter=0.002, seed=4)
    # node 3 misses one answer (G002); node 2 repeats a toggle bit once (G001), then is
    # stopped: its answers say 04h
    lost = min(f for f in frames if f[1] == 0x703 and f[2] != "R" and f[0] > 30.0)
    frames.remove(lost)
    twice = sorted(f for f in frames if f[1] == 0x702 and f[2] != "R" and f[0] > 40.0)[:2]
    frames.remove(twice[1])
    frames.append((twice[1][0], 0x702, twice[0][2]))
    frames = [(t, c, f"{int(d, 16) & 0x80 | 0x04:02X}" if c == 0x702 and d != "R"
               and t > 45.0 else d) for t, c, d in frames]
    frames += [(45.0, 0x000, "0202")]
    log = _write(tmp_path / "guarded.log", frames)
    whole = _check(log, None, ec_compact.Compaction(), settings)
    assert sorted({f.rule for f in whole.findings}) == ["G001", "G002"]
    for compaction in (FORCED, TIGHT, ec_compact.Compaction(above=0)):
        res = _check(log, None, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert _guard_dropped(res) > len(frames) / 2
        guard = res.model.decoded.ec_guard_runs
        assert {k % 128 for k in guard} == {2, 3}  # node 4 beats: heartbeat runs of its own
        assert all(bool((g.n % 4 == 0).all()) for g in guard.values())  # whole exchanges,
        for m, w in zip(res.model.nodes(), whole.model.nodes(), strict=True):  # even answers
            for kind in range(6):
                assert m.ec.count(kind) == w.ec.count(kind), (m.node, kind)
    # the settings as shipped (but the threshold): a few rows per node and run stay
    assert len(res.model.decoded.ec["ts"]) < len(frames) / 8
    key = {"input_id": "x"}
    assert node_rows(res, key, "d", {}) == node_rows(whole, key, "d", {})
    html = renderer("html")
    assert DATE.sub("", html([res], OPTIONS)) == DATE.sub("", html([whole], OPTIONS))


def test_a_guarded_node_a_limit_cuts_or_that_beats_too_is_read_back_whole(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    frames = _guarded(2, 0.011, 30.0, 0.1, jitter=0.001)
    frames += _guarded(3, 0.023, 30.0, 0.35)  # requests 0.35 s apart, life time 0.3 s: G003
    frames += _guarded(5, 0.037, 15.0, 0.1)  # answers guarding, then produces heartbeats:
    frames += _heartbeats(5, 15.06, 30.0, 0.1)  # G004 (a run of each kind)
    log = _write(tmp_path / "limits.log", frames)
    net = tmp_path / "network.toml"
    net.write_text("".join(f"[nodes.{n}]\nguard_time_ms = 100\nlife_time_factor = 3\n\n"
                           for n in (2, 3)))
    whole = _check(log, net, ec_compact.Compaction(), settings)
    restored = _spy_restore(settings)
    res = _check(log, net, FORCED, settings)
    assert restored == [{3, 5}]
    assert _reports(res) == _reports(whole)
    assert {f.rule for f in res.findings} == {"G003", "G004"}
    assert set(res.model.decoded.ec_guard_runs) == {2}  # node 2 still compacted


def test_late_requests_on_either_side_of_a_run_stay_two_findings(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # life time 100 ms, requests 99.5 ms apart but twice 100.5 ms (inside the steady band):
    # G003's pairs around the dropped run between them must not read as consecutive. The
    # late ones are kept near the start command and near the end; the commands to node 7
    # do not concern node 5 and divide none of its runs.
    net = tmp_path / "network.toml"
    net.write_text("[nodes.5]\nguard_time_ms = 100\nlife_time_factor = 1\n")
    frames = [(0.0, 0x705, "00"), (0.001, 0x000, "0105"), (2.0, 0x000, "0107"),
              (15.0, 0x000, "0107")]
    t = 0.05
    for i in range(200):
        frames += [(round(t, 6), 0x705, "R"), (round(t + 0.002, 6), 0x705, f"{i % 2 << 7 | 5:02X}")]
        t += 0.1005 if i in (5, 196) else 0.0995
    log = _write(tmp_path / "late.log", frames)
    whole = _check(log, net, ec_compact.Compaction(), settings)
    assert [f.rule for f in whole.findings] == ["G003", "G003"]
    for compaction in (ec_compact.Compaction(above=0), FORCED):
        res = _check(log, net, compaction, settings)
        assert _guard_dropped(res) > 300
        assert _reports(res) == _reports(whole), compaction
    assert len(res.model.decoded.ec_guard_runs[node_key(0, 5)].pos) > 1  # FORCED's chunks
    res = _check(log, net, ec_compact.Compaction(above=0), settings)
    assert len(res.model.decoded.ec_guard_runs[node_key(0, 5)].pos) == 1


def test_a_guarding_run_with_pauses_as_long_as_a_silence_is_read_back_whole(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # the causes' silences on the channel: node 5's 0.5 s pauses while nodes 3 and 4 are
    # quiet are silences, which stand-ins for its dropped exchanges cannot place
    frames = [(0.0, 0x703, "00"), (0.0, 0x704, "00"), (0.0, 0x705, "00")]
    frames += _heartbeats(3, 0.05, 20.0, 0.1) + _heartbeats(4, 0.07, 20.0, 0.2)
    frames = [f for f in frames if not (f[1] == 0x703 and 10.0 < f[0] < 12.0)]
    frames = [f for f in frames if not (f[1] == 0x704 and 9.0 < f[0] < 13.0)]
    frames += _guarded(5, 0.011, 20.0, 0.5)
    log = _write(tmp_path / "silence.log", frames)
    whole = _check(log, None, ec_compact.Compaction(), settings)
    assert any(c["kind"] == "silence" for f in whole.findings for c in f.causes or [])
    restored = _spy_restore(settings)
    for compaction in (FORCED, TIGHT, ec_compact.Compaction(above=0)):
        res = _check(log, None, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert restored[-1] == {5} and not res.model.decoded.ec_guard_runs  # read back


def test_a_rule_that_looks_long_after_a_command_keeps_what_it_needs(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # S004 with obey_ms = 3000: the first report 3 s after an ignored stop is kept (the
    # frames after a command are kept for at least the obey time, not only for protect_s)
    frames = [(0.0, 0x705, "00"), (0.002, 0x000, "0105"), (10.0201, 0x000, "0205")]
    frames += _guarded(5, 0.01, 20.0, 0.05)
    frames += [(0.0, 0x706, "00"), (0.003, 0x000, "0106"), (10.0202, 0x000, "0206")]
    frames += _heartbeats(6, 0.02, 20.0, 0.05)
    log = _write(tmp_path / "obey.log", frames)
    profile = load_profile("default")
    profile["S004"].params["obey_ms"] = 3000.0
    rules = select_rules(profile, [], [])

    def check(compaction: ec_compact.Compaction) -> InputResult:
        settings.setattr(ec_compact, "SETTINGS", compaction)
        return check_input(str(log), 0, profile, rules)

    whole = check(ec_compact.Compaction())
    assert sorted(f.node or 0 for f in whole.findings if f.rule == "S004") == [5, 6]
    for compaction in (FORCED, TIGHT, ec_compact.Compaction(above=0)):
        res = check(compaction)
        assert _guard_dropped(res) > 0 and _dropped(res) > 0
        assert _reports(res) == _reports(whole), compaction


GUARD_TIGHT = ec_compact.Compaction(above=0, chunk=31, margin=4, protect_s=0.15, min_run=1)


def _random_guarded_network(rng: random.Random) -> list[tuple[float, str, int, str]]:
    """Nodes 5-7 on one or two channels guarded at 50-500 ms, with lost, repeated, late
    and other-state answers, boot-ups, commands, SDO writes of 100Ch/100Dh, stray and
    malformed heartbeats, pauses, a switch to heartbeats, lines out of time order (the
    review's generator: its seed 2147 found the guarding margin counted frames)."""
    fr: list[tuple[float, str, int, str]] = []
    for ch in ["can0"] if rng.random() < 0.7 else ["can0", "can1"]:
        for node in rng.sample([5, 6, 7], rng.randint(1, 3)):
            _random_guarded_node(rng, ch, node, fr)
    fr.sort(key=lambda f: f[0])
    if rng.random() < 0.2:  # time goes backwards: a few lines moved
        for _ in range(rng.randint(1, 3)):
            i, j = rng.randrange(len(fr)), rng.randrange(len(fr))
            fr.insert(j, fr.pop(i))
    return [(round(t, 6), ch, c, d) for t, ch, c, d in fr]


def _random_guarded_node(rng: random.Random, ch: str, node: int,
                         fr: list[tuple[float, str, int, str]]) -> None:
    t = rng.uniform(0, 0.1)
    if rng.random() < 0.8:
        fr.append((0.0, ch, 0x700 + node, "00"))
    period = rng.choice([0.1, 0.1, 0.2, 0.05, 0.5])
    lat = rng.choice([0.001, 0.002, 0.01, 0.3])
    state = 0x05 if rng.random() < 0.8 else 0x7F
    tog = 0
    n = rng.randint(50, 300)
    rtr = rng.choice(["R", "R", "R1", "R0"])
    for _ in range(n):
        tt = t + (rng.uniform(-0.002, 0.002) if rng.random() < 0.5 else 0)
        fr.append((tt, ch, 0x700 + node, rtr))
        r = rng.random()
        late = lat * 400 if 0.023 <= r < 0.026 else lat  # very late
        if 0.015 <= r < 0.02:  # another state
            state = rng.choice([0x04, 0x05, 0x7F])
        if 0.02 <= r < 0.023:  # a boot-up instead
            fr.append((tt + lat, ch, 0x700 + node, "00"))
            tog = 0
        elif r >= 0.01:  # (below: a lost answer) from 0.01 to 0.015 the toggle repeats
            fr.append((tt + late, ch, 0x700 + node, f"{tog << 7 | state:02X}"))
            tog ^= int(r >= 0.015)
        t += _random_event(rng, ch, node, tt, period, state, fr) + period
    if rng.random() < 0.2:  # it switches to heartbeats
        fr.extend((t + i * 0.1, ch, 0x700 + node, f"{state:02X}")
                  for i in range(rng.randint(10, 100)))


def _random_event(rng: random.Random, ch: str, node: int, tt: float, period: float,
                  state: int, fr: list[tuple[float, str, int, str]]) -> float:
    """Now and then something between two exchanges; the pause it adds (seconds)."""
    rr = rng.random()
    half = tt + period / 2
    if rr < 0.005:
        fr.append((half, ch, 0x000, rng.choice(["8100", f"81{node:02X}", f"02{node:02X}",
                                                 f"01{node:02X}", "0100", f"82{node:02X}"])))
    elif rr < 0.008:  # life time factor written
        v = rng.choice([1, 2, 3, 5])
        fr.append((half, ch, 0x600 + node, f"2F0D10000{v}000000"))
        fr.append((half + 0.001, ch, 0x580 + node, "600D100000000000"))
    elif rr < 0.010:  # guard time written
        fr.append((half, ch, 0x600 + node, "2B0C100064000000"))
        fr.append((half + 0.001, ch, 0x580 + node, "600C100000000000"))
    elif rr < 0.012:
        fr.append((tt + period / 3, ch, 0x700 + node, f"{state:02X}"))  # a stray heartbeat
    elif rr < 0.014:
        fr.append((tt + period / 3, ch, 0x700 + node, "0500"))  # a malformed one
    elif rr < 0.016:
        return period * rng.uniform(2, 30)  # a long pause
    return 0.0


def test_random_guarded_networks_give_the_same_reports(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    net = tmp_path / "network.toml"
    net.write_text("[nodes.5]\nguard_time_ms = 100\nlife_time_factor = 2\n"
                   "[nodes.6]\nguard_time_ms = 100\nlife_time_factor = 3\n")
    dropped = 0
    for seed in [2147, *range(16)]:
        rng = random.Random(seed)
        frames = _random_guarded_network(rng)
        network = rng.choice([None, net])
        log = tmp_path / f"g{seed}.log"
        log.write_text("".join(f"({1_700_000_000 + t:.6f}) {ch} {c:03X}#{d}\n"
                               for t, ch, c, d in frames))
        whole = _reports(_check(log, network, ec_compact.Compaction(), settings))
        for compaction in (FORCED, GUARD_TIGHT):
            res = _check(log, network, compaction, settings)
            dropped += _guard_dropped(res)
            assert _reports(res) == whole, (seed, compaction)
    assert dropped > 1000


# -- a master that repeats its commands (keep-alive) ---------------------------------------

def _runs_across_commands(res: InputResult, guard: bool = False) -> int:
    """How many dropped heartbeat (guarding) runs hold a valid NMT command that reaches
    their node."""
    n = 0
    for cm in res.model.channels:
        nmt = cm.nmt
        for m in cm.nodes.values():
            runs = m.ec.guard_runs if guard else m.ec.runs
            if runs is None or not len(runs.pos):
                continue
            reach = np.sort(nmt.idx[nmt.valid & ((nmt.target == 0) | (nmt.target == m.node))])
            a, b = m.ec.idx[runs.pos - 1], m.ec.idx[runs.pos]
            n += int((np.searchsorted(reach, a) != np.searchsorted(reach, b)).sum())
    return n


def _random_keepalive_network(rng: random.Random) -> tuple[list[tuple[float, str, int, str]],
                                                            bool]:
    """A master that sends "start all" every 0.2-1 s among the heartbeats of nodes 2-8,
    with direct stops, starts, pre-operationals and resets now and then, nodes that
    carry a command out late (stale reports first) or not at all, boot-ups, lost
    heartbeats, nodes that answer node guarding instead, and sometimes a master (node 1)
    with heartbeats of its own that obeys its own commands (CANopenNode) or not (Lely);
    whether the network file names it."""
    end = rng.uniform(20, 50)
    every = rng.choice([0.2, 0.3, 0.5, 1.0])
    commands: list[tuple[float, int, int]] = []  # time, specifier, target
    t = rng.uniform(0.3, 0.6)
    while t < end:
        commands.append((t, 0x01, 0))
        if rng.random() < 0.04:  # a direct command between two keep-alives
            commands.append((t + every / 2, rng.choice([0x01, 0x02, 0x80, 0x81, 0x82]),
                             rng.randint(1, 8)))
        t += every * rng.uniform(0.97, 1.03)
    commands.sort()
    fr = [(round(c[0], 6), "can0", 0x000, f"{c[1]:02X}{c[2]:02X}") for c in commands]
    nodes = rng.sample(range(2, 9), rng.randint(2, 5))
    master = rng.random() < 0.6
    for node in ([1] if master else []) + nodes:
        period = rng.choice([0.05, 0.1, 0.1, 0.2])
        delay = rng.choice([0.0, 0.0, 0.02, 0.15])  # how long a command takes it
        ignores = rng.random() < 0.15 and node != 1  # ignores stops
        obeys_self = rng.random() < 0.5
        guarded = node != 1 and rng.random() < 0.3  # answers node guarding instead
        state, boot_at, toggle = 0x7F, 0.0, 0
        fr.append((0.0 + node * 0.001, "can0", 0x700 + node, "00"))
        t, k = node * 0.003 + period, 0
        while t < end:
            while k < len(commands) and commands[k][0] <= t - delay:
                ct, cs, target = commands[k]
                k += 1
                if target not in (0, node) or (node == 1 and target == 0 and not obeys_self):
                    continue
                if cs in (0x81, 0x82):
                    boot_at = ct + 0.03
                    state, toggle = 0x7F, 0
                elif not (ignores and cs == 0x02):
                    state = {0x01: 0x05, 0x02: 0x04, 0x80: 0x7F}[cs]
            if boot_at:
                fr.append((round(boot_at, 6), "can0", 0x700 + node, "00"))
                boot_at = 0.0
            tt = round(t + rng.uniform(-0.001, 0.001), 6)
            if guarded:
                fr.append((tt, "can0", 0x700 + node, "R"))
                tt = round(tt + 0.002, 6)
            if rng.random() > 0.005:  # else lost
                fr.append((tt, "can0", 0x700 + node, f"{toggle << 7 | state:02X}"))
                toggle ^= int(guarded)
            t += period
    fr.sort(key=lambda f: f[0])
    return fr, master


def test_random_keepalive_networks_give_the_same_reports(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # A master repeating "start all" kept every heartbeat: a command divided every run
    # (5 M frames: 429 MB; 20 M: 1.36 GB). A repeated command that a node has obeyed
    # since the same command before no longer does, nor one to another node.
    named = tmp_path / "master.toml"
    named.write_text("master = 1\n")
    dropped = across = guard_across = 0
    for seed in range(14):
        rng = random.Random(seed)
        frames, master = _random_keepalive_network(rng)
        log = tmp_path / f"k{seed}.log"
        log.write_text("".join(f"({1_700_000_000 + t:.6f}) {ch} {c:03X}#{d}\n"
                               for t, ch, c, d in frames))
        network = named if master and rng.random() < 0.7 else None
        whole = _reports(_check(log, network, ec_compact.Compaction(), settings))
        for compaction in (FORCED, TIGHT, ec_compact.Compaction(above=0)):
            res = _check(log, network, compaction, settings)
            dropped += _dropped(res)
            dropped += _guard_dropped(res)
            across += _runs_across_commands(res)
            guard_across += _runs_across_commands(res, guard=True)
            assert _reports(res) == whole, (seed, compaction)
    assert dropped > 10_000 and across > 50 and guard_across > 20


def test_a_master_that_obeys_its_own_keepalive_is_read_back_whole(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # CANopenNode's master applies its own "start all" to itself: its heartbeats report
    # 05h across every repeat like a slave's. Whether it obeyed each broadcast is read
    # from its next report, which a run would put behind later broadcasts: the master,
    # once the timeline knows it, is read back whole; the slaves stay compacted.
    frames = [(0.0, 0x701, "00"), (0.001, 0x702, "00"), (0.002, 0x703, "00")]
    frames += [(0.5 + i * 0.5, 0x000, "0100") for i in range(80)]
    for n in (1, 2, 3):
        frames += [(t, c, "7F" if t < 0.5 else d) for t, c, d in
                   _heartbeats(n, 0.01 * n + 0.05, 40.0, 0.05)]
    log = _write(tmp_path / "self.log", frames)
    network = tmp_path / "master.toml"
    network.write_text("master = 1\n")
    whole = _check(log, network, ec_compact.Compaction(), settings)
    restored = _spy_restore(settings)
    assert _reports(_check(log, network, FORCED, settings)) == _reports(whole)
    for compaction in (ec_compact.Compaction(above=0),):  # FORCED's chunks hold few repeats
        restored.clear()
        res = _check(log, network, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert restored == [{node_key(0, 1)}]  # the master alone
        assert _runs_across_commands(res) > 0
        # what the reports do not show: the broadcasts the master is taken to have obeyed
        # (79 of them; 5 if its runs had stayed)
        own = [next(m for m in r.model.nodes() if m.node == 1).own_command_idx
               for r in (res, whole)]
        assert len(own[0]) == 79 and own[0].tolist() == own[1].tolist()
    assert _dropped(res) > 1000  # the slaves: 2 x 790 heartbeats, 2 x 16 or so kept


def test_a_repeated_command_a_node_ignores_divides_its_runs(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # Nodes 5 (heartbeats) and 6 (guarded) keep reporting 05h through three stops, the
    # last two repeats: each is a finding (S004), so each repeat must stay an event for
    # them with the reports right after it. Node 7 carries the stops out: its repeats
    # pass inside its runs.
    frames = [(0.0, 0x705, "00"), (0.0, 0x706, "00"), (0.0, 0x707, "00"),
              (0.3, 0x000, "0100")]
    frames += [(t, 0x000, "0200") for t in (10.0, 20.0, 30.0)]
    frames += [(t, c, "7F" if t < 0.3 else d) for t, c, d in _heartbeats(5, 0.05, 40.0, 0.05)]
    frames += [(t, c, "7F" if t < 0.3 else "04" if t > 10.0 else "05")
               for t, c, _d in _heartbeats(7, 0.07, 40.0, 0.05)]
    frames += [(t, c, d if d == "R" else f"{int(d, 16) & 0x80 | (0x7F if t < 0.3 else 5):02X}")
               for t, c, d in _guarded(6, 0.06, 40.0, 0.05)]
    log = _write(tmp_path / "ignored.log", frames)
    whole = _check(log, None, ec_compact.Compaction(), settings)
    s004 = sorted((f.node, int(f.time) - 1_700_000_000) for f in whole.findings
                  if f.rule == "S004")
    assert s004 == [(5, 10), (5, 20), (5, 30), (6, 10), (6, 20), (6, 30)]
    for compaction in (FORCED, TIGHT, GUARD_TIGHT, ec_compact.Compaction(above=0)):
        res = _check(log, None, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert _dropped(res) > 500 and _guard_dropped(res) > 500
    assert _runs_across_commands(res) > 0  # node 7's, across the repeated stops


def test_a_report_that_changes_in_the_obey_time_after_a_repeat_keeps_its_finding(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # The review's case: "start all" every second; 2 ms after the sixth, node 2 still
    # reports 05h (queued before it), then STOPPED from 12 ms on. S004 reads the first
    # report past the obey time (102 ms): the repeat must stay an event, with the rows
    # of its obey time, or the finding moves to the next kept report.
    period = 0.009
    frames = [(0.0, 0x702, "00")] + [(0.3 + i, 0x000, "0100") for i in range(12)]
    beats = [round(0.002 + i * period, 6) for i in range(int(12 / period))]
    stop = [t for t in beats if t > 5.3][1]
    frames += [(t, 0x702, "7F" if t < 0.3 else "04" if t >= stop else "05") for t in beats]
    log = _write(tmp_path / "late_change.log", frames)
    whole = _check(log, None, ec_compact.Compaction(), settings)
    s004 = [f.message for f in whole.findings if f.rule == "S004"]
    assert s004[0] == ("node 2 reports STOPPED 0.102 s after NMT start (broadcast) "
                       "(expected OPERATIONAL)")
    for compaction in (ec_compact.Compaction(above=0), FORCED, TIGHT):
        res = _check(log, None, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
    assert _dropped(_check(log, None, ec_compact.Compaction(above=0), settings)) > 300


def test_repeated_stops_with_a_line_back_in_time_give_the_same_report(
        settings: pytest.MonkeyPatch) -> None:
    # The review's case (its fuzz seed 26, reduced: tests/data/README.md): node 4
    # stopped, "stop all" every 100 ms, one heartbeat written 3 s late. The timeout it
    # leaves is ended by the first report that is evidence (not queued before a stop);
    # compacted, that report had been dropped inside a run of repeats (OFFLINE to
    # 17.18 s instead of 15.28 s). Two guards: no repeat where time goes back, and a
    # node with a run inside OFFLINE is read back whole; either one alone mends it.
    log = REPO / "tests" / "data" / "compaction" / "repeated_stops_back_in_time.log"
    whole = _reports(_check(log, None, ec_compact.Compaction(), settings))
    assert '"state": "OFFLINE", "start": 1700000015.012191, "end": 1700000015.282243' in whole[
        "json"]
    for compaction in (ec_compact.Compaction(above=0), FORCED, TIGHT, GUARD_TIGHT,
                       ec_compact.Compaction(above=0, chunk=4096, margin=2, protect_s=0.0,
                                             min_run=1)):
        assert _reports(_check(log, None, compaction, settings)) == whole, compaction


def _uploads(node: int, reads: list[tuple[float, int, int]]) -> list[tuple[float, int, str]]:
    """A manager's expedited SDO uploads from `node` (time, index, sub), each answered
    1 ms later with the value 0191h (1000h) or 1 (1018h)."""
    out = []
    for t, index, sub in reads:
        obj = f"{index & 0xFF:02X}{index >> 8:02X}{sub:02X}"
        value = "91010000" if index == 0x1000 else "01000000"
        out += [(t, 0x600 + node, f"40{obj}00000000"),
                (round(t + 0.001, 6), 0x580 + node, f"43{obj}{value}")]
    return out


def _named_master(tmp_path: Path) -> Path:
    network = tmp_path / "master.toml"
    network.write_text("master = 1\n")
    return network


def test_a_slaves_report_after_its_masters_boot_up_is_kept(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # The review's case (older than the keep-alive change): the manager (node 1, named
    # in the network file) boots again at 10 s while node 2 beats steadily; the boot
    # process anchored there ends with node 2's first OPERATIONAL report after it
    # (P005, letter L) and its probes come 0.9 s later. Compacted, that report lay
    # inside a run: P007 (start before boot complete) and a failed gate. Every boot-up
    # now divides every node's runs on its channel.
    frames = [(0.0, 0x701, "00"), (0.0005, 0x702, "00")]
    frames += [(0.25 + i * 0.5, 0x000, "0100") for i in range(10)]
    frames += [(t, c, "7F" if t < 0.25 else d) for t, c, d in _heartbeats(2, 0.005, 12.0, 0.01)]
    frames += [(10.0, 0x701, "00"), *_uploads(2, [(10.9, 0x1000, 0), (10.91, 0x1018, 1)])]
    log = _write(tmp_path / "master_reboot.log", frames)
    network = _named_master(tmp_path)
    whole = _check(log, network, ec_compact.Compaction(), settings)
    assert [(f.rule, f.node) for f in whole.findings if f.rule.startswith("P")] == [("P005", 2)]
    for compaction in (ec_compact.Compaction(above=0), FORCED, TIGHT):
        res = _check(log, network, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert _dropped(res) > 400  # of 1,200 heartbeats


def test_a_boot_processes_evidence_inside_a_run_is_read_back_whole(
        tmp_path: Path, settings: pytest.MonkeyPatch) -> None:
    # A process anchored on the manager's boot-up at 10 s stays incomplete; its evidence
    # is node 2's first report after the last transfer (1018h:02 at 11.8 s), which lay
    # inside a run (SDO transfers do not divide runs): compacted, the evidence moved to
    # 13.835 s. Such a node is now read back whole before the boot report is made.
    frames = [(0.0, 0x701, "00"), (0.0005, 0x702, "00")]
    frames += [(t, c, "7F") for t, c, _d in _heartbeats(2, 0.005, 14.0, 0.01)]
    frames += [(10.0, 0x701, "00"),
               *_uploads(2, [(10.3, 0x1000, 0), (10.31, 0x1018, 1), (11.8, 0x1018, 2)])]
    log = _write(tmp_path / "evidence.log", frames)
    network = _named_master(tmp_path)
    whole = _check(log, network, ec_compact.Compaction(), settings)
    assert whole.boot is not None
    report = whole.boot.nodes[("can0", 2)]
    assert report.status == "incomplete" and report.process is not None
    assert report.process.evidence is not None
    assert round(report.process.evidence.time - 1_700_000_000, 3) == 11.805
    for compaction in (ec_compact.Compaction(above=0), FORCED, TIGHT):
        restored = _spy_restore(settings)
        res = _check(log, network, compaction, settings)
        assert _reports(res) == _reports(whole), compaction
        assert {node_key(0, 2)} in restored

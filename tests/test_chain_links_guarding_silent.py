"""The chain links `life_guarding` and `producer_silent` and the stand-ins `pdo_gap` and
`sync_gap` (SPEC_COMM §9.3.4) on CANopenNode
recordings.

`life_guarding`: in `samples/canopennode/master_unplugged.log` the master is unplugged at
about 4.0 s; guarded node 4 (life time 100 ms x 3, written by SDO at boot) gets no request
after 3.97 s and its stack reports the life-guarding event with EMCY 8130h (CANopenNode's
`CO_Node_Guarding.c`: error bit 1Bh, info 0) at 4.270265 s (line 244), then answers the
next request with PRE-OPERATIONAL (6.0786 s). Ground truth: the README's table and the log.

`producer_silent`: a node unplugged while it produces a PDO. No recording of ours has
that, so the test derives one from `samples/canopennode/pdo/rpdo_producer_stopped.log`:
node 2's frames (182h, 702h, 582h, 082h) and the NMT commands to it are taken out from
just after its last TPDO (3.966909 s, line 265) to 6.5 s, as if it had been unplugged there
instead of stopped. Node 3's own frames (its RPDO timeout EMCY 8250h at 4.218791 s, its
drop to PRE-OPERATIONAL) are what the stack really did when 182h stopped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from nmtcheck.api import check

SAMPLES = Path(__file__).resolve().parents[1] / "samples" / "canopennode"


def _report(log: Path, network: Path) -> dict[str, Any]:
    out: dict[str, Any] = check([log], network=network).to_dict()
    return out


def _findings(report: dict[str, Any], rule: str, node: int | None = None
              ) -> list[dict[str, Any]]:
    return [f for f in report["findings"] if f["rule"] == rule
            and (node is None or f["node"] == node)]


def _chain_under(causes: list[dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    return [c for c in causes if c["kind"] == kind]


def test_life_guarding_explains_the_guarded_nodes_8130h() -> None:
    report = _report(SAMPLES / "master_unplugged.log", SAMPLES / "network.toml")
    s005 = _findings(report, "S005", 4)
    assert len(s005) == 1
    causes = s005[0]["causes"]
    assert [c["link"] for c in causes] == ["error_behaviour", "life_guarding"]
    emcy, gap = causes
    assert emcy["code"] == "8130h" and emcy["line"] == 244
    assert gap["kind"] == "guarding_gap" and gap["node"] == 4
    assert gap["depth"] == 2 and gap["parent"] == 0
    assert gap["end"] == emcy["time"]
    # the last request to node 4 before its EMCY: no request in the 300 ms before it
    lines = (SAMPLES / "master_unplugged.log").read_text().splitlines()
    last = [n for n, text in enumerate(lines[:243], 1) if text.endswith("704#R1")][-1]
    assert gap["line"] == last
    assert emcy["time"] - gap["time"] > 0.300
    assert "life time 300 ms" in gap["text"]


def test_life_guarding_needs_the_life_time(tmp_path: Path) -> None:
    """Without 100Ch/100Dh (the master's SDO writes taken out) the pause is no evidence."""
    lines = (SAMPLES / "master_unplugged.log").read_text().splitlines()
    kept = [t for t in lines if "#2B0C10" not in t and "#2F0D10" not in t
            and "#2B0D10" not in t]
    assert len(kept) < len(lines)
    log = tmp_path / "no_life_time.log"
    log.write_text("\n".join(kept) + "\n")
    report = _report(log, SAMPLES / "network.toml")
    for f in report["findings"]:
        assert not _chain_under(f["causes"], "guarding_gap"), f


def _unplugged_producer(tmp_path: Path) -> Path:
    lines = (SAMPLES / "pdo" / "rpdo_producer_stopped.log").read_text().splitlines()
    t0 = float(lines[0].split(")")[0][1:])
    kept = []
    for text in lines:
        t = float(text.split(")")[0][1:]) - t0
        frame = text.split()[2]
        if 3.967 < t < 6.5 and (frame.split("#")[0] in ("182", "702", "582", "082")
                                 or frame in ("000#0202", "000#0102")):
            continue
        kept.append(text)
    log = tmp_path / "producer_unplugged.log"
    log.write_text("\n".join(kept) + "\n")
    return log


def test_producer_silent_explains_the_rpdo_gap(tmp_path: Path) -> None:
    log = _unplugged_producer(tmp_path)
    report = _report(log, SAMPLES / "pdo" / "network_rpdo_producer_stopped.toml")
    start = report["inputs"][0]["start"]
    d004 = _findings(report, "D004")
    assert [(f["node"], round(f["time"] - start, 6)) for f in d004] == [(3, 4.216909)]
    silent = _chain_under(d004[0]["causes"], "node_silent")
    assert len(silent) == 1
    entry = silent[0]
    assert entry["link"] == "producer_silent" and entry["node"] == 2
    assert round(entry["time"] - start, 6) == 3.966909  # its last frame, the last 182h
    assert entry["end"] is not None and entry["end"] - start > 6.5  # its next frame
    assert "H001 timeout" in entry["text"]
    # and under node 3's drop to PRE-OPERATIONAL: EMCY 8250h -> D004 -> node 2's silence
    s005 = _findings(report, "S005", 3)
    assert [c["link"] for c in s005[0]["causes"]] == [
        "error_behaviour", "rpdo_timeout", "producer_silent"]


def test_producer_silent_not_for_a_stopped_producer() -> None:
    """Stopped by NMT, node 2 goes on sending heartbeats: `producer_state`, never
    `producer_silent`."""
    report = _report(SAMPLES / "pdo" / "rpdo_producer_stopped.log",
                     SAMPLES / "pdo" / "network_rpdo_producer_stopped.toml")
    d004 = _findings(report, "D004")
    assert len(d004) == 1
    links = {c["link"] for c in d004[0]["causes"]}
    assert "producer_state" in links and "producer_silent" not in links


# -- the measured stand-ins of SPEC_COMM §9.3.4 (`pdo_gap`, `sync_gap`): where D004 or Y001
# could not judge, the gap that CANopenNode's own EMCY reports still explains it


def test_pdo_gap_stands_in_where_d004_has_no_deadline(tmp_path: Path) -> None:
    """rpdo_producer_stopped's network file without node 3's deadline (1400h:05): D004 is
    not evaluated, and node 3's EMCY 8250h (line 282) is explained by the measured gap of
    182h after its last frame (line 265), and that gap by the stop of node 2 (line 268)."""
    text = (SAMPLES / "pdo" / "network_rpdo_producer_stopped.toml").read_text()
    network = tmp_path / "network.toml"
    network.write_text(text.replace("event_timer_ms = 250          # the deadline\n", ""))
    assert network.read_text() != text
    report = _report(SAMPLES / "pdo" / "rpdo_producer_stopped.log", network)
    assert not _findings(report, "D004")
    [s005] = _findings(report, "S005", 3)
    chain = [(c["kind"], c["link"], c["depth"], c["basis"], c["line"]) for c in s005["causes"]]
    assert chain == [("emcy", "error_behaviour", 1, None, 282),
                     ("pdo_gap", "rpdo_timeout", 2, "measured", 265),
                     ("nmt", "producer_state", 3, None, 268)]


def test_no_pdo_gap_where_d004_judged() -> None:
    """With the deadline known, D004 is the verdict: the chain names it, no stand-in."""
    report = _report(SAMPLES / "pdo" / "rpdo_producer_stopped.log",
                     SAMPLES / "pdo" / "network_rpdo_producer_stopped.toml")
    [s005] = _findings(report, "S005", 3)
    kinds = [c["kind"] for c in s005["causes"]]
    assert "finding" in kinds and "pdo_gap" not in kinds


def test_sync_gap_stands_in_where_y001_is_not_run() -> None:
    """sync_producer_stopped with Y001 left out: each consumer's EMCY 8100h (lines 436,
    437) is explained by the measured SYNC gap after the last SYNC (line 433)."""
    report = check([SAMPLES / "sync_emcy" / "sync_producer_stopped.log"],
                   ignore=["Y001"]).to_dict()
    s005 = _findings(report, "S005")
    assert [f["node"] for f in s005] == [3, 4]
    for f, line in zip(s005, (437, 436), strict=True):
        chain = [(c["kind"], c["link"], c["depth"], c["basis"], c["line"]) for c in f["causes"]]
        assert chain == [("emcy", "error_behaviour", 1, None, line),
                         ("sync_gap", "sync_timeout", 2, "measured", 433)]

"""`nmtcheck timeline --format csv|json` and SPEC §9.4.2: one `kind: lss` row per LSS
exchange, with the L finding at it.

The recordings are CANopenNode's (samples/canopennode/lss/, README there): what is
expected comes from the log's frames and from what the stack's LSS master said each call
returned (the `.events` file), never from nmtcheck's other reports.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import stack_recording as recording
from conftest import SAMPLES, Checker
from conftest import run_cli as run

from nmtcheck.cli.timeline import COLUMNS

FOLDER = SAMPLES / "canopennode" / "lss"


def _rows(name: str, fmt: str, tmp_path: Path) -> str:
    res = run("timeline", str((FOLDER / f"{name}.log").resolve()), "--format", fmt,
              "--isolated", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _lss_rows(name: str, tmp_path: Path) -> list[dict[str, Any]]:
    rows = json.loads(_rows(name, "json", tmp_path))
    assert all(set(r) == set(COLUMNS) for r in rows)
    return sorted((r for r in rows if r["kind"] == "lss"), key=lambda r: r["line"])


def _master_calls(name: str) -> list[str]:
    return [e.text.removeprefix("master: ") for e in recording.events(FOLDER / f"{name}.log")
            if e.device == "master" and e.text.startswith("master: ")
            and "changeTimeout" not in e.text]


def _answer(frames: list[recording.Frame], request: recording.Frame
            ) -> recording.Frame | None:
    """The 7E4h frame with the request's command specifier before the next request."""
    later = [f for f in frames if f.line > request.line]
    nxt = next((f.line for f in later if f.can_id == 0x7E5), None)
    cs = {"43": "44"}.get(request.data[:2], request.data[:2])
    return next((f for f in later if f.can_id == 0x7E4 and f.data[:2] == cs
                 and (nxt is None or f.line < nxt)), None)


def test_one_row_per_request_with_its_answer(tmp_path: Path) -> None:
    """Selective switch, inquire node-ID, configure node-ID 5, store, switch to waiting:
    every call returned OK (the stack's word), so no row names a rule; each row runs from
    the request to its answer; the configure row carries node 5."""
    name = "lss_configure_store"
    assert _master_calls(name) == ["select 300:4644:0:1 -> OK", "inquire_node -> OK, value "
                                   "000000FF", "node 5 -> OK", "store -> OK", "deselect -> OK"]
    log = FOLDER / f"{name}.log"
    start = recording.t0(log)
    frames = recording.frames(log)
    requests = [f for f in frames if f.can_id == 0x7E5]
    rows = _lss_rows(name, tmp_path)
    assert [r["line"] for r in rows] == [f.line for f in requests]
    for r, q in zip(rows, requests, strict=True):
        answer = _answer(frames, q)
        assert round(r["start"] - start, 6) == q.t
        assert round(r["end"] - start, 6) == (q.t if answer is None else answer.t)
        assert (r["channel"], r["cob_id"], r["code"], r["rule"]) == (
            "can0", "7E5h", q.data[:2] + "h", None)
        assert r["text"].startswith("LSS ")
    configure = next(r for r in rows if r["code"] == "11h")
    assert configure["node"] == 5 and configure["text"] == "LSS configure node-ID 5 -> ok"
    assert [r["node"] for r in rows if r["code"] != "11h"] == [None] * (len(rows) - 1)
    table = [r for r in csv.DictReader(io.StringIO(_rows(name, "csv", tmp_path)))
             if r["kind"] == "lss"]
    assert sorted((int(r["line"]), r["code"], r["node"], r["start"]) for r in table) == [
        (r["line"], r["code"], "" if r["node"] is None else str(r["node"]),
         f"{r['start']:.6f}") for r in rows]


def test_error_answer_names_l003_at_its_row(tmp_path: Path) -> None:
    """The store the slave answered with 1 (not supported; the master got
    OK_ILLEGAL_ARGUMENT): L003 on the store row, ending at that answer."""
    name = "lss_store_error"
    assert "store -> OK_ILLEGAL_ARGUMENT" in _master_calls(name)
    log = FOLDER / f"{name}.log"
    frames = recording.frames(log)
    answer = next(f for f in frames if f.can_id == 0x7E4 and f.data.startswith("1701"))
    rows = _lss_rows(name, tmp_path)
    [failed] = [r for r in rows if r["rule"]]
    assert (failed["rule"], failed["code"]) == ("L003", "17h")
    assert round(failed["end"] - recording.t0(log), 6) == answer.t
    assert "not supported" in failed["text"] and "L003: " in failed["text"]


def test_unanswered_request_names_l001_at_its_row(tmp_path: Path) -> None:
    """Configure bit timing that the slave (without bit-rate support) drops: the master
    timed out; L001 on the 13h row, not on the next request (the finding's own frame)."""
    name = "lss_bitrate_silent"
    assert "bitrate 125 -> TIMEOUT" in _master_calls(name)
    log = FOLDER / f"{name}.log"
    request = next(f for f in recording.frames(log) if f.can_id == 0x7E5
                   and f.data.startswith("13"))
    rows = _lss_rows(name, tmp_path)
    [failed] = [r for r in rows if r["rule"]]
    assert (failed["rule"], failed["line"]) == ("L001", request.line)
    assert failed["start"] == failed["end"]  # no answer came


def test_l002_and_l006_rows(checker: Checker) -> None:
    """SPEC §9.5.4's vectors: L002 on the unanswered selective switch, L006 on the
    configure node-ID whose node-ID no boot-up adopted (node 7)."""
    from nmtcheck.cli.timeline import timeline_rows
    l002 = ("(10.000000) can0 7E5#4000030000000000\n(10.001000) can0 7E5#4144460000000000\n"
            "(10.002000) can0 7E5#4200000000000000\n(10.003000) can0 7E5#4301000000000000\n"
            "(12.000000) can0 7E5#0400000000000000\n")
    rows = [r for r in timeline_rows(checker.run(l002)) if r["kind"] == "lss"]
    assert [(r["code"], r["rule"]) for r in rows] == [
        ("40h", None), ("41h", None), ("42h", None), ("43h", "L002"), ("04h", None)]
    l006 = ("(10.000000) can0 7E5#0401000000000000\n(10.001000) can0 7E5#5E00000000000000\n"
            "(10.002000) can0 7E4#5EFF000000000000\n(10.003000) can0 7E5#1107000000000000\n"
            "(10.004000) can0 7E4#1100000000000000\n(10.005000) can0 7E5#0400000000000000\n"
            "(16.000000) can0 080#\n")
    rows = [r for r in timeline_rows(checker.run(l006)) if r["kind"] == "lss"]
    assert [(r["code"], r["node"], r["rule"]) for r in rows if r["rule"]] == [
        ("11h", 7, "L006")]
    assert [r["end"] for r in rows if r["code"] == "11h"] == [10.004]

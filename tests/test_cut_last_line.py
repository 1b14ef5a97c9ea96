"""A text log that ends inside its last line: a recording killed mid-write, a file
copied while the logger was writing it. What is left of the line can still parse as a
frame with fewer bytes (`000#01` of `000#0102`, `703#` of `703#05`): a malformed NMT
command (C002) or heartbeat (C003), an error that failed the gate on a healthy network.
Such a frame is a skipped record and the input is truncated (I002); a last line without
a newline that holds a whole frame (a pasted log saved without one) is read."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import SAMPLES, Checker, run_cli


def _lines(path: Path, upto: int) -> list[str]:
    return path.read_text().splitlines(keepends=True)[:upto]


@pytest.mark.parametrize(("log", "line"), [
    ("canopennode/healthy.log", 16),  # (…) can0 000#0102: start node 2
    ("canopennode/healthy.log", 6),  # 000#8200: reset communication
    ("lely/healthy.log", 64),  # 000#0104
    ("canopennode/healthy.log", 12),  # a heartbeat
])
def test_a_log_cut_inside_its_last_line_keeps_the_verdict_of_what_was_whole(
        checker: Checker, log: str, line: int) -> None:
    lines = _lines(SAMPLES / log, line)
    before, last = "".join(lines[:-1]), lines[-1].rstrip("\n")
    whole = checker.run(before + last + "\n")
    upto = checker.run(before)
    assert not [f for f in whole.findings if f.rule in ("C002", "C003")]
    for cut in range(1, len(last)):
        res = checker.run(before + last[:cut])
        rules = {f.rule for f in res.findings}
        assert not rules & {"C002", "C003"}, (cut, last[:cut], res.findings)
        errors = sorted(f.rule for f in res.findings if f.severity == "error")
        assert errors in ([f.rule for f in upto.findings if f.severity == "error"],
                          [f.rule for f in whole.findings if f.severity == "error"]), (
            cut, last[:cut], res.findings)
        # what is left of the line is a frame (read), a short one (cut: I002), or no
        # record (skipped: I003)
        assert res.stats.frames in (upto.stats.frames, upto.stats.frames + 1)
        if res.stats.frames == upto.stats.frames:
            assert "I003" in rules and res.stats.skipped_lines[-1] == line
            if last[:cut].endswith("#") or last[:cut].endswith("#01"):
                assert res.stats.truncated and "I002" in rules, (cut, last[:cut])


def test_a_short_frame_on_a_whole_last_line_is_still_judged(checker: Checker) -> None:
    """With its newline, the line was written whole: `000#01` is a malformed NMT command."""
    text = "(1.000000) can0 701#00\n(1.100000) can0 000#01\n"
    assert [f.rule for f in checker.run(text).findings] == ["C002"]
    cut = checker.run(text.rstrip("\n"))
    assert [f.rule for f in cut.findings] == ["I002", "I003"]
    assert cut.stats.frames == 1 and cut.stats.skipped_lines == [2]


def test_a_pasted_log_without_a_final_newline_keeps_its_last_frame(checker: Checker) -> None:
    """A whole frame on the last line, no newline after it: read as it is."""
    text = "(1.000000) can0 701#00\n(1.100000) can0 000#0101"
    res = checker.run(text)
    assert res.stats.frames == 2 and not res.stats.truncated and res.findings == []
    asc = ("date Sat Nov 21 22:22:54.144 2026\nbase hex  timestamps absolute\n"
           " 0.000000 1  701             Rx   d 1 00\n"
           " 0.100000 1  0               Rx   d 2 01 01")
    res = checker.run(asc, suffix=".asc")
    assert res.stats.frames == 2 and not res.stats.truncated and res.findings == []


def test_strict_makes_a_cut_last_line_an_input_error(tmp_path: Path) -> None:
    log = tmp_path / "cut.log"
    log.write_text("(1.000000) can0 701#00\n(1.100000) can0 000#01")
    res = run_cli("check", "--strict", str(log), cwd=tmp_path)
    assert res.returncode == 2 and f"{log}:2: " in res.stderr and "cut off" in res.stderr


def test_a_compressed_log_cut_while_written(tmp_path: Path) -> None:
    """`candump -L can0 | gzip > run.log.gz` killed, or copied while written: the stream
    is damaged (I002) and its last line read is cut (`704#` of `704#05`): a skipped
    record, not a C003 error. A whole compressed log keeps its findings."""
    import gzip

    text = (SAMPLES / "canopennode" / "healthy.log").read_bytes()
    end = text.index(b"704#05", len(text) // 2) + len(b"704#")
    whole = gzip.compress(text)
    cut = gzip.compress(text[:end])
    # a stream cut inside the compressed data: its deflate blocks up to the cut
    damaged = cut[:-8]  # no CRC and size trailer: the decompressor reports the damage
    log = tmp_path / "run.log.gz"
    log.write_bytes(damaged)
    res = run_cli("check", "--isolated", str(log), "--format", "json", "--fail-on", "never",
                  cwd=tmp_path)
    report = json.loads(res.stdout)
    rules = [f["rule"] for f in report["findings"]]
    assert report["inputs"][0]["truncated"] and "I002" in rules, rules
    assert not {"C002", "C003"} & set(rules), rules
    (tmp_path / "whole.log.gz").write_bytes(whole)
    res = run_cli("check", "--isolated", str(tmp_path / "whole.log.gz"), cwd=tmp_path)
    assert res.returncode == 0, res.stdout

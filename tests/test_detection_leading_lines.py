"""SPEC section 1: text detection looks past leading lines that are no record.

A note added by hand above a log (`# recorded on bench 3`) or a banner did make the whole
log an "unknown log format" (exit 2), while the same line in the middle of the log is one
skipped record. Now detection looks past up to MAX_LEADING_LINES such lines (within the
first HEAD_BYTES) for every text format. Those lines are skipped records with their line
numbers: they show in the input summary, and `--strict` makes the first of them fatal.
Blank lines are no records and are not counted. A format's own comment lines are not
counted either: an ASC `//` comment before the header is one of these. A file of nothing
but such lines is still an unknown format.

Each case is a real log (the samples, the readers' generated logs of every text format,
the corpus files that are there) with a comment line put in front. It must be detected as
the same format and give the same frames, each one line further down. It must report
exactly one skipped record, at line 1.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES, needs_shared, read_columns, shared_file
from hostile_logs import TEXT_WRITERS, format_of, network_frames

from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import InputError
from nmtcheck.readers import FORMATS, MAX_LEADING_LINES, TEXT_FORMATS, detect_format, open_input
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.settings.profiles import load_profile

# A note without a comment mark: a skipped record. (A `# ...` line is a comment, a non-frame
# record: tests/test_readers_pasted.py.)
COMMENT = b"recorded on bench 3"
SAMPLE_FILES = sorted(p for p in SAMPLES.rglob("*") if p.suffix in (".log", ".asc"))
# Real text logs of the shared corpus (LGPL/GPL, so not copied into tests/data, except
# multiGeneratorCAN.log): used when ../shared is beside the checkout.
CORPUS_TEXT = [
    "css-electronics/multiGeneratorCAN.log",
    "python-can/logfile.asc",
    "python-can/issue_1256.asc",
    "python-can/test_CanMessage_V1_0_BUS1.trc",
    "python-can/test_CanMessage_V1_1.trc",
    "python-can/test_CanMessage_V1_3.trc",
    "python-can/test_CanMessage_V2_0_BUS1.trc",
    "python-can/test_CanMessage_V2_1.trc",
    "python-can/test_CanMessage.trc",
    "savvycan/GVRET_Log.csv",
    "wireshark/canlogger-cl2000.txt",
]


def _cases() -> list[object]:
    cases: list[object] = [
        pytest.param(lambda p=p: p.read_bytes(), id=p.relative_to(SAMPLES).as_posix())
        for p in SAMPLE_FILES]
    cases += [pytest.param(lambda w=w: TEXT_WRITERS[w](network_frames()), id=f"written-{w}")
              for w in sorted(TEXT_WRITERS)]
    for rel in CORPUS_TEXT:
        shared = f"corpus/third_party/{rel}"
        cases.append(pytest.param(lambda shared=shared: shared_file(shared).read_bytes(),
                                  id=f"corpus-{rel}", marks=needs_shared(shared)))
    return cases


def _newline(raw: bytes) -> bytes:
    """The log's own line end, so the comment line looks like the rest (TRC: CRLF)."""
    end = raw.find(b"\n")
    return b"\r\n" if end > 0 and raw[end - 1:end] == b"\r" else b"\n"


def _commented(raw: bytes, *lines: bytes) -> bytes:
    nl = _newline(raw)
    return b"".join(line + nl for line in lines) + raw


def _findings(path: Path) -> list[tuple[object, ...]]:
    """Everything a finding says, but for the I-rules (they report the input itself)."""
    profile = load_profile("default")
    res = check_input(str(path), 0, profile, select_rules(profile, [], []))
    return [(f.rule, f.channel, f.node, f.time, f.frame_index, f.line, f.message)
            for f in res.findings if not f.rule.startswith("I")]


def test_every_text_format_is_covered() -> None:
    assert sorted({format_of(w) for w in TEXT_WRITERS}) == sorted(TEXT_FORMATS)
    assert set(TEXT_FORMATS) <= set(FORMATS)
    assert SAMPLE_FILES, "no samples found"


@pytest.mark.parametrize("make", _cases())
def test_a_comment_line_on_top_is_one_skipped_record_at_line_1(make, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    raw = make()
    fmt = detect_format(raw[:65536])
    assert fmt in TEXT_FORMATS  # the log as recorded is detected
    assert detect_format(_commented(raw, COMMENT)[:65536]) is None  # not by the sniffers alone
    original = tmp_path / "original"
    original.write_bytes(raw)
    commented = tmp_path / "commented"
    commented.write_bytes(_commented(raw, COMMENT))

    before, cols_before = read_columns(original)
    after, cols_after = read_columns(commented)
    assert before.skipped == 0  # the cases are clean logs
    assert after.format == before.format == fmt
    assert after.skipped == 1 and after.skipped_lines == [1]
    # the same frames, each one line further down
    assert after.frames == before.frames > 0
    for f in dataclasses.fields(FrameBatch):
        if f.name == "line":
            assert np.array_equal(cols_after["line"], cols_before["line"] + 1)
        else:
            assert np.array_equal(cols_after[f.name], cols_before[f.name]), f.name
    for key in ("ignored", "extended", "error_frames", "remote_frames", "fd_frames", "dropped",
                "backwards_timestamps", "truncated", "start", "end", "channels"):
        assert getattr(after, key) == getattr(before, key), key


@pytest.mark.parametrize("name", ["healthy.log", "heartbeat_loss.log", "reset_no_bootup.log"])
def test_findings_are_the_same_one_line_further_down(name: str, tmp_path: Path) -> None:
    commented = tmp_path / name
    commented.write_bytes(_commented((SAMPLES / name).read_bytes(), COMMENT))
    # a message that names a line (B003's reset) names the one a line further down too
    expected = [(*f[:5], f[5] + 1 if isinstance(f[5], int) else f[5],
                 re.sub(r"\(line (\d+)\)", lambda m: f"(line {int(m[1]) + 1})", str(f[6])))
                for f in _findings(SAMPLES / name)]
    assert _findings(commented) == expected


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
def test_cli_summary_and_strict(writer: str, tmp_path: Path) -> None:
    log = tmp_path / f"bench3-{writer}.txt"  # a suffix that tells no format
    log.write_bytes(_commented(TEXT_WRITERS[writer](network_frames()), COMMENT))
    res = run_cli("check", str(log), "--format", "json", "--fail-on", "never", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)["inputs"][0]
    assert (summary["format"], summary["skipped"], summary["skipped_lines"]) == (
        format_of(writer), 1, [1])
    # --strict: the first unparseable record is fatal, naming file and line
    res = run_cli("check", str(log), "--strict", cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr
    assert lines[0].startswith(f"nmtcheck: {log}:1: cannot parse {format_of(writer)} record"), (
        lines[0])


def test_blank_and_comment_lines_on_top(tmp_path: Path) -> None:
    """Blank lines are no records; each non-blank line on top is one, with its number."""
    log = tmp_path / "notes.log"
    raw = (SAMPLES / "healthy.log").read_bytes()
    log.write_bytes(b"\n   \n" + _commented(raw, b"# bench 3", b"", b"=== banner ===", b"\t"))
    stats, _ = read_columns(log)
    assert stats.format == "candump"
    assert stats.skipped == 1 and stats.skipped_lines == [5]  # the banner
    assert stats.ignored == stats.notes == 1  # `# bench 3`: a comment, no skipped record


def test_asc_comment_before_the_header_is_the_formats_own(tmp_path: Path) -> None:
    """`//` lines are ASC comments anywhere in the file, so also above the header."""
    raw = TEXT_WRITERS["asc"](network_frames())
    log = tmp_path / "commented.asc"
    log.write_bytes(_commented(raw, b"// exported by hand, bench 3"))
    assert detect_format(log.read_bytes()) == "asc"
    stats, _ = read_columns(log)
    assert stats.format == "asc" and stats.skipped == 0


def test_compressed_log_with_a_comment_on_top(tmp_path: Path) -> None:
    log = tmp_path / "bench3.log.gz"
    log.write_bytes(gzip.compress(_commented((SAMPLES / "healthy.log").read_bytes(), COMMENT)))
    stats, _ = read_columns(log)
    assert stats.format == "candump" and stats.skipped_lines == [1]


def test_as_many_leading_lines_as_the_limit(tmp_path: Path) -> None:
    raw = (SAMPLES / "healthy.log").read_bytes()
    notes = [b"note %d" % i for i in range(1, MAX_LEADING_LINES + 1)]
    log = tmp_path / "many.log"
    log.write_bytes(_commented(raw, *notes))
    stats, _ = read_columns(log)
    assert stats.format == "candump" and stats.skipped == MAX_LEADING_LINES
    assert stats.skipped_lines == list(range(1, 11))  # the first few are kept
    # one more: detection gives up (it only looks at the first lines), as before
    log.write_bytes(_commented(raw, *notes, b"one too many"))
    with pytest.raises(InputError, match="unknown log format"):
        open_input(str(log))


@pytest.mark.parametrize("content", [
    b"# recorded on bench 3\n",
    b"# recorded on bench 3\n# nothing was logged\n\n",
    b"// only ASC-style comments\r\n// and nothing else\r\n",
], ids=["one-comment", "comments-and-blank", "asc-comments"])
def test_a_file_of_only_comments_is_still_an_unknown_format(content: bytes,
                                                             tmp_path: Path) -> None:
    log = tmp_path / "notes.log"
    log.write_bytes(content)
    res = run_cli("check", str(log), cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"nmtcheck: {log}: unknown log format (supported: {', '.join(FORMATS)}; "
        "use --input-format NAME)"]

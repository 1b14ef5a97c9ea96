"""SPEC §1, "Logs as people paste them" and "Logs without timestamps".

Logs pasted into issue threads, notes and e-mails: lines indented by a tab (a markdown code
block), notes after frames (`701#05  # boot-up`), comment and shell-prompt lines, `...`,
candump screen output without `-t`, cansend's bare `ID#DATA`, a `candump -td` paste with a
damaged line. They are read, not rejected, and no line is dropped silently: every line that
is not blank is a frame, a non-frame record (`ignored`; `notes` of them are only a note or a
comment) or a skipped record (counted, line number kept).

The fixtures (tests/data/pasted/, README.md there) are hand-made in the shape of posted
captures; the counts below are by hand, line by line.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import DATA, read_columns, run_cli

from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import InputError
from nmtcheck.readers import (
    InputStats,
    blocks,
    detect_format,
    is_note_line,
    note_follows,
)
from nmtcheck.readers.blocks import REFERENCE_ENV
from nmtcheck.settings.profiles import load_profile

PASTED = DATA / "pasted"


@dataclasses.dataclass
class Expected:
    format: str
    frame_lines: list[int]  # the lines that hold a frame, in order
    skipped_lines: list[int]
    notes: int  # lines that are only a note or a comment
    timestamped: bool
    ts: list[float] | None = None  # None: every frame at 0 s (no timestamps)
    channels: tuple[str, ...] = ("can0",)


EXPECTED: dict[str, Expected] = {
    # ``` fence, user@host prompt, `...`, `^C`, ``` fence: 5 notes; 22 frame lines
    "ros2_canopen_issue_candump_screen.txt": Expected(
        "candump-screen", [*range(3, 21), *range(22, 26)], [], 5, False),
    # prose on top and at the end (skipped), a blank line, tab- and space-indented frames
    "markdown_indented_candump_L.log": Expected(
        "candump", list(range(3, 19)), [1, 20], 0, True,
        [1700000100.000000, 1700000100.000412, 1700000100.001023, 1700000100.050000,
         1700000100.100020, 1700000100.100533, 1700000100.110000, 1700000100.110412,
         1700000100.200011, 1700000100.200540, 1700000100.210000, 1700000100.300007,
         1700000100.310000, 1700000100.400012, 1700000100.410000, 1700000100.500009]),
    # a prompt and a `//` line (notes); `# boot-up`, `<-- here`, `// still …` after frames
    "candump_L_with_notes.log": Expected(
        "candump", [*range(2, 10), *range(11, 17)], [], 2, True,
        [1700000200.000000, 1700000200.000950, 1700000200.001200, 1700000200.200000,
         1700000200.250000, 1700000200.250400, 1700000200.285000, 1700000200.286000,
         1700000201.250000, 1700000201.260000, 1700000201.285000, 1700000201.286000,
         1700000202.250000, 1700000202.260000]),
    # `$ candump -td can0` (a note); line 6 lost its data byte: skipped, its delta kept
    "candump_td_one_damaged_line.txt": Expected(
        "candump-screen", [2, 3, 4, 5, 7, 8, 9, 10, 11], [6], 1, True),  # ts: test below
    # a `#` comment line; `# …` and `<-- …` notes after bare frames; channel `1`
    "cansend_bare_frames.txt": Expected(
        "candump", list(range(2, 10)), [], 1, False, None, ("1",)),
    # a prompt, `....` and `^C` (notes); a `<-- …` note after a frame
    "email_candump_ta_screen.txt": Expected(
        "candump-screen", [2, 3, 4, 6, 7, 8, 9, 10, 11], [], 3, True,
        [1700000300.000000, 1700000300.000512, 1700000300.010000, 1700000301.000480,
         1700000301.010000, 1700000302.000501, 1700000302.010000, 1700000304.700000,
         1700000304.710000]),
    # `can0 ID#DATA`: candump -L with the timestamps left out; a `//` note after a frame
    "iface_frames_without_timestamps.log": Expected(
        "candump", list(range(1, 8)), [], 0, False),
}

# `candump -td` deltas of candump_td_one_damaged_line.txt, line by line from line 2 (the
# damaged line 6 included: its delta counts)
TD_DELTAS = [0.0, 0.100102, 0.000357, 0.099541, 0.100212, 0.000298, 0.099870, 0.100133,
             0.000301, 0.099702]
TD_LINES = list(range(2, 12))


def test_every_fixture_is_covered() -> None:
    names = sorted(p.name for p in PASTED.iterdir() if p.name != "README.md")
    assert names == sorted(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_fixture_reads_whole(name: str) -> None:
    exp = EXPECTED[name]
    path = PASTED / name
    stats, cols = read_columns(path)
    assert stats.format == exp.format
    assert detect_format(path.read_bytes()[:65536]) in (exp.format, None)  # None: leading lines
    # exact counts: frames are the lines that hold a frame
    assert stats.frames == len(exp.frame_lines)
    assert list(cols["line"]) == exp.frame_lines
    assert (stats.skipped, stats.skipped_lines) == (len(exp.skipped_lines), exp.skipped_lines)
    assert (stats.ignored, stats.notes) == (exp.notes, exp.notes)
    # no line is dropped silently: every line that is not blank is accounted for
    lines = path.read_bytes().split(b"\n")
    nonblank = sum(1 for line in lines if line.strip())
    assert stats.frames + stats.skipped + stats.ignored == nonblank
    assert stats.timestamped is exp.timestamped
    assert tuple(stats.channels) == exp.channels
    ts = cols["ts"]
    if exp.timestamped:
        assert np.all(np.diff(ts) >= 0)  # file order, no timestamp going back
        assert stats.backwards_timestamps == 0
        if exp.ts is not None:
            np.testing.assert_allclose(ts, exp.ts, rtol=0, atol=1e-7)
    else:
        assert np.all(ts == 0.0) and stats.start == stats.end == 0.0
        assert np.all(np.diff(cols["line"]) > 0) and list(cols["index"]) == list(
            range(stats.frames))


def test_td_deltas_after_a_damaged_line_do_not_shift() -> None:
    _, cols = read_columns(PASTED / "candump_td_one_damaged_line.txt")
    total, expected = 0.0, []
    for line, delta in zip(TD_LINES, TD_DELTAS, strict=True):
        total += delta
        if line != 6:
            expected.append(total)
    np.testing.assert_allclose(cols["ts"], expected, rtol=0, atol=1e-9)
    # the frame after the damaged line is 0.100212 s (its delta) + 0.000298 s after line 5's
    assert cols["ts"][4] - cols["ts"][3] == pytest.approx(0.100212 + 0.000298, abs=1e-9)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_fixture_through_the_cli(name: str, tmp_path: Path) -> None:
    exp = EXPECTED[name]
    res = run_cli("check", str(PASTED / name), "--format", "json", cwd=tmp_path)
    assert res.returncode in (0, 1), res.stdout + res.stderr
    summary = json.loads(res.stdout)["inputs"][0]
    assert (summary["format"], summary["frames"], summary["skipped"], summary["ignored"]) == (
        exp.format, len(exp.frame_lines), len(exp.skipped_lines), exp.notes)
    assert summary["skipped_lines"] == exp.skipped_lines
    findings = json.loads(res.stdout)["findings"]
    assert "I001" not in {f["rule"] for f in findings}


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if e.format == "candump"))
def test_fast_and_reference_paths_agree(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    assert_same_reading(PASTED / name, monkeypatch)


# --- helpers ------------------------------------------------------------------------------


def write(tmp_path: Path, lines: list[str], name: str = "pasted.txt") -> Path:
    path = tmp_path / name
    path.write_bytes("".join(line + "\n" for line in lines).encode())
    return path


def _read(path: Path, reference: bool, mp: pytest.MonkeyPatch, **kw: Any
          ) -> tuple[InputStats, dict[str, np.ndarray]]:
    with mp.context() as m:
        if reference:
            m.setenv(REFERENCE_ENV, "1")
        else:
            m.delenv(REFERENCE_ENV, raising=False)
        return read_columns(path, **kw)


def assert_same_reading(path: Path, mp: pytest.MonkeyPatch) -> None:
    fast_stats, fast = _read(path, False, mp)
    ref_stats, ref = _read(path, True, mp)
    assert dataclasses.asdict(fast_stats) == dataclasses.asdict(ref_stats)
    for key in fast:
        np.testing.assert_array_equal(fast[key], ref[key], err_msg=key)


def counts(stats: InputStats) -> tuple[int, int, int, int]:
    return stats.frames, stats.skipped, stats.ignored, stats.notes


# --- 1. leading white space ---------------------------------------------------------------


def test_tab_indented_screen_lines_are_frames(tmp_path: Path) -> None:
    """They were dropped: a file of them read as 0 frames, 0 skipped."""
    path = write(tmp_path, ["\t  can0  701   [1]  00", "\t  can0  701   [1]  05",
                            "\tcan0  702   [1]  05"])
    stats, cols = read_columns(path)
    assert stats.format == "candump-screen"
    assert counts(stats) == (3, 0, 0, 0)
    assert list(cols["line"]) == [1, 2, 3]


def test_tab_indented_stamped_screen_lines_are_frames(tmp_path: Path) -> None:
    path = write(tmp_path, ["\t(1700000000.000100)  can0  701   [1]  00",
                            "\t (1700000000.100100)  can0  701   [1]  05"])
    stats, cols = read_columns(path)
    assert counts(stats) == (2, 0, 0, 0) and stats.timestamped
    assert list(cols["ts"]) == [1700000000.0001, 1700000000.1001]


def test_tab_indented_candump_lines_are_frames(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, ["\t(1700000000.000100) can0 701#00",
                            "\t\t(1700000000.100000) can0 701#05",
                            " \t (1700000000.200000) can0 701#05"], "tabs.log")
    stats, cols = read_columns(path)
    assert stats.format == "candump" and counts(stats) == (3, 0, 0, 0)
    assert list(cols["line"]) == [1, 2, 3]
    assert_same_reading(path, monkeypatch)


def test_error_frame_explanation_lines_belong_to_the_error_frame(tmp_path: Path) -> None:
    """`candump -e` prints an error frame's explanation on tab-indented lines below it: they
    are part of its record. A tab-indented frame there is a frame, and a tab-indented line
    elsewhere is a record of its own."""
    path = write(tmp_path, [
        "  can0  20000004   [8]  00 04 00 00 00 00 00 00   ERRORFRAME",
        "\tcontroller-problem{rx-error-warning}",
        "\terror-counter-tx-rx{{0}{97}}",
        "\t  can0  701   [1]  05",  # a frame, pasted indented, right after the error frame
        "\tcontroller-problem{rx-error-warning}",  # not after an error frame: skipped
        "  can0  702   [1]  05",
    ])
    stats, cols = read_columns(path)
    assert counts(stats) == (3, 1, 0, 0)
    assert stats.skipped_lines == [5]
    assert list(cols["line"]) == [1, 4, 6]
    # a damaged error frame (here: no timestamp in a log with them) keeps its explanation
    path = write(tmp_path, [
        " (1.000000)  can0  701   [1]  05",
        "  can0  20000004   [8]  00 04 00 00 00 00 00 00   ERRORFRAME",
        "\tcontroller-problem{rx-error-warning}",
        " (1.100000)  can0  701   [1]  05",
    ], "damaged.txt")
    stats, _ = read_columns(path)
    assert counts(stats) == (2, 1, 0, 0) and stats.skipped_lines == [2]


# --- 2. notes after a record --------------------------------------------------------------


@pytest.mark.parametrize("line", [
    "701#05  # boot-up",
    "701#05 # boot-up",  # one space, but a note's mark
    "701#05\t# boot-up",
    "701#05   boot-up",
    "701#05  <-- here",
    "701#05 <- here",
    "701#05  ok",
    "701#05  bad",  # hex letters only, not two: a word
    "701#05  (node 1)",
])
def test_note_after_a_bare_frame(line: str, tmp_path: Path) -> None:
    stats, cols = read_columns(write(tmp_path, [line]))
    assert stats.format == "candump" and counts(stats) == (1, 0, 0, 0)
    assert (int(cols["can_id"][0]), int(cols["dlc"][0]), int(cols["data"][0, 0])) == (
        0x701, 1, 5)


@pytest.mark.parametrize("line", [
    "(1700000000.000100) can0 701#05   <-- here",
    "(1700000000.000100) can0 701#05  # boot-up",
    "(1700000000.000100) can0 701#05 R  # received",
    "(1700000000.000100) can0 701#05 // boot-up",
])
def test_note_after_a_candump_frame(line: str, tmp_path: Path,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, [line, "(1700000000.100100) can0 701#05"], "notes.log")
    stats, cols = read_columns(path)
    assert stats.format == "candump" and counts(stats) == (2, 0, 0, 0)
    assert list(cols["ts"]) == [1700000000.0001, 1700000000.1001]
    assert_same_reading(path, monkeypatch)


@pytest.mark.parametrize("line", [
    "  can0  701   [1]  05   # boot-up",
    "can0  701   [1]  05   # boot-up",
    "  can0  701   [1]  05  <-- here",
    "  can0  701   [1]  05 # boot-up",
    "  can0  701   [1]  05   boot-up",
    "can0 701 [1] 05  <-- here",  # SPEC §1's example
])
def test_note_after_a_screen_frame(line: str, tmp_path: Path) -> None:
    stats, _ = read_columns(write(tmp_path, [line, "  can0  701   [1]  05"]))
    assert stats.format == "candump-screen" and counts(stats) == (2, 0, 0, 0)


@pytest.mark.parametrize("lines,skipped", [
    (["(1.0) can0 181#0102", "(1.1) can0 181#0102 X"], [2]),  # a damaged direction flag
    (["(1.0) can0 181#0102", "(1.1) can0 181#1122 3344"], [2]),  # data cut by a space
    (["(1.0) can0 181#0102", "(1.1) can0 181#11  22"], [2]),  # one more byte, not a note
    (["(1.0) can0 181#0102", "(1.1) can0 181#11  FF"], [2]),
    (["(1.0) can0 181#0102", "(1.1) can0 181#00 R extra"], [2]),
    (["  can0  701   [1]  05", "  can0  701   [1]  05  00"], [2]),  # more bytes than [1]
    (["  can0  701   [1]  05", "  can0  701   [1]  05 and more"], [2]),
    (["  can0  701   [1]  05", "  can0  701   [2]  05  # boot-up"], [2]),  # a byte short
])
def test_text_that_looks_like_damage_is_no_note(lines: list[str], skipped: list[int],
                                                tmp_path: Path) -> None:
    stats, _ = read_columns(write(tmp_path, lines))
    assert stats.skipped_lines == skipped
    assert stats.frames == len(lines) - len(skipped)


@pytest.mark.parametrize("text,k,note", [
    (b"701#05  # boot-up", 1, True),
    (b"701#05 # boot-up", 1, True),
    (b"701#05 boot-up", 1, False),
    (b"701#05\tboot-up", 1, True),
    (b"701#05   05", 1, False),
    (b"701#05   ab", 1, False),
    (b"701#05   abc", 1, True),
    (b"701#05   7F", 1, False),
    (b"(1.0) can0 701#05 R   <-- here", 4, True),
])
def test_note_follows(text: bytes, k: int, note: bool) -> None:
    assert note_follows(text, k) is note


# --- 3. lines that are only a note or a comment --------------------------------------------


@pytest.mark.parametrize("line", [
    "# boot-up of node 1", "#", "// comment", "$ candump can0", "$", "user@host:~$ candump -L can0",
    "pi@raspberrypi:~ $ candump -ta can0", "root@box:/tmp# candump any",
    "[user@host ~]$ candump can0", "(venv) user@host:~/ws$ candump can0", "PS C:\\> candump can0",
    "C:\\Users\\me> type run.log", "D:\\logs>ssh pi candump -L can0", "C:\\>",
    "...", "....", "…", "[...]", "(...)", ". . .", "[snip]", "--- snip ---", "```", "```text",
    "~~~", "^C", "\t# indented comment", "   ...",
])
def test_note_lines(line: str) -> None:
    assert is_note_line(line.encode())


@pytest.mark.parametrize("line", [
    "(1.0) can0 701#05", "701#05", "can0 701#05", "  can0  701   [1]  05", "hello world",
    "=== banner ===", "DROPCOUNT: dropped 3", ".", "Here is the log (candump -L can0):",
    "(000.100000)  can0  701   [1]  05",
])
def test_no_note_lines(line: str) -> None:
    assert not is_note_line(line.encode())


def test_note_lines_are_non_frame_records_not_skips(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, [
        "user@host:~$ candump -L can0",
        "(1700000000.000100) can0 701#00",
        "# node 1 booted",
        "// then",
        "...",
        "(1700000000.100100) can0 701#05",
        "garbage here",
        "^C",
    ], "prompt.log")
    stats, cols = read_columns(path)
    assert counts(stats) == (2, 1, 5, 5)
    assert stats.skipped_lines == [7]
    assert list(cols["line"]) == [2, 6]
    assert_same_reading(path, monkeypatch)
    # under --strict a note is no unparseable record: only the garbage line is fatal
    with pytest.raises(InputError) as exc:
        read_columns(path, strict=True)
    assert exc.value.line == 7


def test_many_comment_lines_in_a_large_log(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The fast path counts a block's many `#` lines in bulk, as the reference path does
    one by one: notes, in either path, under --strict too."""
    lines = []
    for i in range(3000):
        lines.append(f"({1700000000 + i / 100:.6f}) can0 701#05")
        if i % 20 == 0:
            lines.append(f"# {i}")
        if i % 500 == 0:
            lines.append(f"\t({1700000000 + i / 100:.6f}) can0 702#05  # indented, a note")
    path = write(tmp_path, lines, "many.log")
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 8192)
    stats, _ = read_columns(path)
    assert counts(stats) == (3006, 0, 150, 150)
    assert_same_reading(path, monkeypatch)
    strict, _ = read_columns(path, strict=True)
    assert counts(strict) == counts(stats)


def test_leading_comment_lines_are_notes_and_prose_is_skipped(tmp_path: Path) -> None:
    path = write(tmp_path, ["# capture from the bench", "$ candump -L can0", "see below:",
                            "(1700000000.000100) can0 701#00"], "lead.log")
    stats, cols = read_columns(path)
    assert stats.format == "candump"
    assert counts(stats) == (1, 1, 2, 2) and stats.skipped_lines == [3]
    assert list(cols["line"]) == [4]


# --- 4. delta timestamps ------------------------------------------------------------------


def test_td_line_with_a_lost_parenthesis_keeps_its_delta(tmp_path: Path) -> None:
    path = write(tmp_path, [
        " (000.000000)  can0  701   [1]  05",
        " (000.200000)  can0  701   [1]  05",
        " (000.100000  can0  701   [1]  05",  # `)` lost: skipped, the delta still counts
        " (000.050000)  can0  701   [1]  05",
        " (000.x00000)  can0  701   [1]  05",  # the delta cannot be read: lost
        " (000.100000)  can0  701   [1]  05",
    ])
    stats, cols = read_columns(path)
    assert stats.skipped_lines == [3, 5]
    np.testing.assert_allclose(cols["ts"], [0.0, 0.2, 0.35, 0.45], atol=1e-9)


# --- 5. logs without timestamps -----------------------------------------------------------


def test_screen_output_without_timestamps(tmp_path: Path) -> None:
    path = write(tmp_path, ["  can0  701   [1]  00", "  can1  701   [1]  00",
                            "  can0  701   [1]  05"])
    stats, cols = read_columns(path)
    assert not stats.timestamped and counts(stats) == (3, 0, 0, 0)
    assert list(cols["ts"]) == [0.0, 0.0, 0.0] and list(cols["line"]) == [1, 2, 3]
    assert stats.channels == ["can0", "can1"]


def test_a_log_with_timestamps_is_still_one(tmp_path: Path) -> None:
    stats, _ = read_columns(write(tmp_path, ["(1.0) can0 701#05"], "one.log"))
    assert stats.timestamped


@pytest.mark.parametrize("lines,frames,skipped,timestamped", [
    # a log with timestamps: a line without one is a skipped record, not a frame at 0 s
    (["(1.0) can0 701#00", "can0 701#05", "(1.2) can0 701#05"], [1, 3], [2], True),
    (["701#05", "(1.0) can0 701#00", "(1.2) can0 701#05"], [2, 3], [1], True),
    # one without: a line with a timestamp is
    (["can0 701#00", "(1.0) can0 701#05", "can0 701#05"], [1, 3], [2], False),
    (["  can0  701   [1]  00", " (1.000000)  can0  701   [1]  05", "  can0  701   [1]  05"],
     [1, 3], [2], False),
    ([" (1.000000)  can0  701   [1]  00", "  can0  701   [1]  05",
      " (1.100000)  can0  701   [1]  05"], [1, 3], [2], True),
])
def test_with_and_without_timestamps_mixed(lines: list[str], frames: list[int],
                                           skipped: list[int], timestamped: bool,
                                           tmp_path: Path) -> None:
    stats, cols = read_columns(write(tmp_path, lines))
    assert list(cols["line"]) == frames and stats.skipped_lines == skipped
    assert stats.timestamped is timestamped


def test_bare_frames_of_every_kind(tmp_path: Path) -> None:
    path = write(tmp_path, ["701#00", "vcan0 123#R", "123#R2", "18FF0102#0011", "123##1AABB",
                            "000#0100 T", "80000000#"])
    stats, cols = read_columns(path)
    assert stats.format == "candump" and not stats.timestamped
    assert counts(stats) == (7, 0, 0, 0)
    assert stats.channels == ["1", "vcan0"]
    assert list(cols["rtr"]) == [False, True, True, False, False, False, False]
    assert list(cols["ext"]) == [False, False, False, True, False, False, True]
    assert list(cols["fd"]) == [False, False, False, False, True, False, False]


def test_detection_of_bare_lines_does_not_take_other_text() -> None:
    assert detect_format(b"701#05\n") == "candump"
    assert detect_format(b"can0 701#05\n") == "candump"
    assert detect_format(b"  can0  701   [1]  05\n") == "candump-screen"
    assert detect_format(b"(1.0) can0 701#05\n") == "candump"
    assert detect_format(b"hello world\n") is None
    assert detect_format(b"70#05\n") is None
    assert detect_format(b"1.0 can0 701#05\n") is None


# --- 6. I001 says why nothing was read ----------------------------------------------------


def _i001(path: Path) -> str:
    profile = load_profile("default")
    res = check_input(str(path), 0, profile, select_rules(profile, ["I001"], []))
    (finding,) = [f for f in res.findings if f.rule == "I001"]
    return finding.message


def test_i001_names_the_kinds_of_lines(tmp_path: Path) -> None:
    path = write(tmp_path, ["# bench 3", "(1.0) can0 18FF0102#05",
                            *[f"(1.{i}) can0 70#05" for i in range(1, 11)], "// end"], "bad.log")
    message = _i001(path)
    assert "13 lines" in message
    assert "1 frame (1 extended)" in message
    assert "10 skipped (first at line 3: CAN-ID must be 3 or 8 hex digits" in message
    assert "2 notes or comments" in message
    assert "input-format" not in message  # the format is right: the lines are damaged


def test_i001_every_line_skipped_suggests_the_format(tmp_path: Path) -> None:
    path = write(tmp_path, ["(1.0) can0 70#05", "(1.1) can0 70#05"], "skipped.log")
    message = _i001(path)
    assert "2 lines: no frame, 2 skipped (first at line 1: " in message
    assert "--input-format" in message and "is --input-format right?" not in message


@pytest.mark.parametrize("name", ["heartbeat_loss.log", "heartbeat_loss.asc"])
@pytest.mark.parametrize("bom", ["utf-16-le", "utf-16-be"])
def test_a_utf16_log_is_read_as_its_text(name: str, bom: str, tmp_path: Path) -> None:
    """Windows PowerShell 5.1 writes `ssh pi candump -L can0 > run.log` as UTF-16 with a
    BOM and CRLF line ends. It was an unknown format, and in a directory a skipped file
    that let the gate pass over a real H001: it is read as the text it holds."""
    from conftest import SAMPLES

    text = (SAMPLES / name).read_text()
    log = tmp_path / "logs" / name
    log.parent.mkdir()
    encoded = text.replace("\n", "\r\n").encode(bom)
    log.write_bytes((b"\xff\xfe" if bom == "utf-16-le" else b"\xfe\xff") + encoded)
    profile = load_profile()
    rules = select_rules(profile, [], [])
    want = check_input(str(SAMPLES / name), 0, profile, rules)
    got = check_input(str(log), 0, profile, rules)
    assert (got.stats.format, got.stats.frames, got.stats.skipped) == (
        want.stats.format, want.stats.frames, want.stats.skipped)
    assert [(f.rule, f.node, f.time, f.line) for f in got.findings] == [
        (f.rule, f.node, f.time, f.line) for f in want.findings]
    res = run_cli("check", str(log.parent), cwd=tmp_path)
    assert res.returncode == 1 and "H001" in res.stdout and "no log (skipped)" not in res.stdout


def test_td_paste_of_one_node_whose_deltas_never_decrease(tmp_path: Path) -> None:
    """`candump -td can0,703:7FF`: one node's 100 ms heartbeat whose jitter happens to
    grow never goes down, so it looked like -tz (five heartbeats in 0.1 ms: H001, timeout
    0). Read as offsets, every frame after the second would come within a twentieth of
    the first gap: deltas. A -tz log keeps growing and stays offsets."""
    deltas = ["0.000000", "0.099981", "0.100002", "0.100033", "0.100079", "0.100102"]
    td = write(tmp_path, [f" ({d})  can0  703   [1]  05" for d in deltas])
    _stats, cols = read_columns(td)
    assert np.diff(cols["ts"]).round(6).tolist() == [float(d) for d in deltas[1:]]
    offsets = ["0.000000", "0.100000", "0.200000", "0.300000", "0.400000", "0.500000"]
    tz = tmp_path / "tz.txt"
    tz.write_text("".join(f" ({d})  can0  703   [1]  05\n" for d in offsets))
    _stats, cols = read_columns(tz)
    assert (cols["ts"] - cols["ts"][0]).round(6).tolist() == [float(d) for d in offsets]
    res = run_cli("check", str(td), cwd=tmp_path)
    assert res.returncode == 0, res.stdout

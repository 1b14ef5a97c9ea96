"""Hostile input, property-based: whatever bytes a reader is given, the outcome is a report
whose counts account for every record, or an input error (exit 2) — never any other
exception. Truncation and corruption stay local: what comes before the damage is read as if
the damage were not there.

Runs are deterministic (`derandomize`) and bounded by `max_examples` so the suite stays fast
and CI never flakes; `NMTCHECK_HYPOTHESIS=explore` runs many more random examples locally.
"""

from __future__ import annotations

import dataclasses
import gzip
import itertools
import json
import lzma
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zstandard
from hostile_logs import (
    BINARY_WRITERS,
    PCAP_RECORD,
    TEXT_WRITERS,
    Frame,
    format_of,
    mcap_json,
    network_frames,
    record_lines,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import InputError, NmtcheckError
from nmtcheck.readers import FORMATS, MAX_TIMESTAMP_S, InputStats, open_input
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.reporters import renderer
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

EXPLORE = os.environ.get("NMTCHECK_HYPOTHESIS") == "explore"


def bounded(examples: int) -> settings:
    """Few deterministic examples in CI; many random ones when exploring."""
    return settings(max_examples=examples * 40 if EXPLORE else examples, deadline=None,
                    derandomize=not EXPLORE, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow, HealthCheck.data_too_large])


PROFILE = load_profile("default")
# these tests count every record as a frame or a skipped one: an input mostly skipped is
# read through, not refused as unreadable (I003 unreadable_share, tested in
# test_gate_issue39.py)
PROFILE["I003"].params["unreadable_share"] = 1.0
RULES = select_rules(PROFILE, [], [])
FRAMES = network_frames()
TEXT_SEEDS = {name: write(FRAMES) for name, write in TEXT_WRITERS.items()}
BINARY_SEEDS = {name: write(FRAMES) for name, write in BINARY_WRITERS.items()}
SEEDS = {**TEXT_SEEDS, **BINARY_SEEDS}
TEXT_FORMATS = sorted({format_of(name) for name in TEXT_WRITERS})


def check(path: Path, data: bytes, input_format: str | None = None) -> InputResult | InputError:
    """The whole pipeline on `data`: a result whose reports all render, or an input error
    of one line. Any other exception fails the test (it would be exit 2 'internal error')."""
    path.write_bytes(data)
    try:
        res = check_input(str(path), 0, PROFILE, RULES, input_format=input_format)
    except NmtcheckError as exc:
        assert isinstance(exc, InputError), exc
        assert "\n" not in str(exc) and str(exc).startswith(str(path)), str(exc)
        return exc
    for name in ("text", "json", "csv"):
        renderer(name)([res], {"fail_on": "error", "quiet": False})
    return res


def assert_accounted(res: InputResult | InputError, data: bytes) -> None:
    """Every record line of a text log is a frame, a skipped record or a non-frame record."""
    if isinstance(res, InputError):
        return
    s = res.stats
    if s.format in TEXT_FORMATS:
        assert s.frames + s.skipped + s.ignored == len(record_lines(s.format, data)), (
            s.frames, s.skipped, s.ignored)
    assert s.frames >= 0 and s.skipped >= 0 and s.ignored >= 0


def columns(path: Path, data: bytes, input_format: str | None = None
            ) -> tuple[InputStats, dict[str, np.ndarray]]:
    """All frames of `data` as whole columns."""
    path.write_bytes(data)
    opened = open_input(str(path), input_format)
    batches = list(opened.batches)
    names = [f.name for f in dataclasses.fields(FrameBatch)]
    if not batches:
        empty = {n: np.zeros(0, np.int64) for n in names}
        empty["data"] = np.zeros((0, 8), np.uint8)
        return opened.stats, empty
    return opened.stats, {n: np.concatenate([getattr(b, n) for b in batches]) for n in names}


def frames_by_line(cols: dict[str, np.ndarray]) -> dict[int, tuple[object, ...]]:
    """line -> (ts, channel, id, flags, dlc, data) of the text formats' frames."""
    return {int(cols["line"][i]): (float(cols["ts"][i]), int(cols["chan"][i]),
                                   int(cols["can_id"][i]), bool(cols["ext"][i]),
                                   bool(cols["rtr"][i]), bool(cols["err"][i]),
                                   int(cols["dlc"][i]), cols["data"][i].tobytes())
            for i in range(len(cols["ts"]))}


def findings(res: InputResult) -> list[tuple[object, ...]]:
    """Everything a finding says, its frame index and line included."""
    return [(f.rule, f.channel, f.node, round(f.time, 9), f.frame_index, f.line, f.message)
            for f in res.findings]


def network_findings(res: InputResult) -> list[tuple[object, ...]]:
    """`findings` without those of the input rules (I), which judge the log itself."""
    return [f for f in findings(res) if not str(f[0]).startswith("I")]


NASTY = st.sampled_from([b"\x00", b"\r", b"\n", b"\r\n", b"\xff\xfe", b"\xef\xbb\xbf", b"\xc3",
                         b"-", b"_", b"nan", b"inf", b"9" * 40, b"9" * 5000, b"\t", b";", b",",
                         b"#", b"(", b")", b"[", b"]", b" ", b"0x", b"\x1b[31m"])
EDIT = st.tuples(st.floats(0, 1), st.sampled_from(["replace", "insert", "delete"]),
                 st.one_of(NASTY, st.binary(min_size=1, max_size=8)))


def apply_edits(data: bytes, edits: list[tuple[float, str, bytes]]) -> bytes:
    """Replace, insert or delete bytes at relative positions (so any seed fits)."""
    out = bytearray(data)
    for where, kind, blob in edits:
        at = int(where * len(out))
        if kind == "replace":
            out[at:at + len(blob)] = blob
        elif kind == "insert":
            out[at:at] = blob
        else:
            del out[at:at + len(blob)]
    return bytes(out)


# --- any bytes, any reader ----------------------------------------------------------------


@pytest.mark.parametrize("input_format", [None, *FORMATS])
@bounded(25)
@given(data=st.binary(max_size=3000))
def test_arbitrary_bytes_give_a_report_or_an_input_error(tmp_path: Path, data: bytes,
                                                          input_format: str | None) -> None:
    assert_accounted(check(tmp_path / "log", data, input_format), data)


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(25)
@given(lines=st.lists(st.binary(max_size=120).map(lambda b: b.replace(b"\n", b" ")),
                      max_size=30))
def test_arbitrary_lines_after_a_valid_header(tmp_path: Path, writer: str,
                                              lines: list[bytes]) -> None:
    """Garbage lines after the first valid records (so the format is sniffed and any header
    read): each is a frame, a skipped or a non-frame record."""
    seed = TEXT_SEEDS[writer].split(b"\n")
    data = b"\n".join(seed[:20] + lines + seed[20:])
    res = check(tmp_path / "log", data, format_of(writer))
    assert_accounted(res, data)


# --- truncation ---------------------------------------------------------------------------


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(30)
@given(cut=st.floats(0, 1))
def test_text_log_cut_anywhere_reads_every_whole_line(tmp_path: Path, writer: str,
                                                      cut: float) -> None:
    """A log cut at any byte: each line before the cut gives the frame it gives in the
    whole log; the cut line may give a frame or a skipped record; nothing else."""
    seed = TEXT_SEEDS[writer]
    data = seed[:int(cut * len(seed))]
    res = check(tmp_path / "cut", data, format_of(writer))
    assert_accounted(res, data)
    if isinstance(res, InputError):  # only a log cut before its first record is refused
        assert data.count(b"\n") < record_lines(format_of(writer), seed)[0], res
        return
    _, whole = columns(tmp_path / "whole", seed)
    _, part = columns(tmp_path / "cut", data, format_of(writer))
    complete = data.count(b"\n")
    expected = {k: v for k, v in frames_by_line(whole).items() if k <= complete}
    got = frames_by_line(part)
    assert {k: v for k, v in got.items() if k <= complete} == expected
    assert set(got) - set(expected) <= {complete + 1}


def _pcapng_block_ends(data: bytes) -> list[int]:
    ends, pos = [], 0
    while pos < len(data):
        pos += int.from_bytes(data[pos + 4:pos + 8], "little")
        ends.append(pos)
    return ends


def _blf_container_ends(data: bytes) -> set[int]:
    """Where a cut leaves only whole containers (their padding may be cut or not)."""
    pos = int.from_bytes(data[4:8], "little")  # the file header's size
    ends = {pos}
    while pos < len(data):
        size = int.from_bytes(data[pos + 8:pos + 12], "little")
        ends |= set(range(pos + size, pos + size + size % 4 + 1))
        pos += size + size % 4
    return ends


@pytest.mark.parametrize("writer", sorted(BINARY_WRITERS))
@bounded(30)
@given(cut=st.floats(0, 1))
def test_binary_log_cut_anywhere_reads_up_to_the_cut(tmp_path: Path, writer: str,
                                                     cut: float) -> None:
    """A binary log cut at any byte: a report with the frames before the cut, marked
    truncated, or an input error when not even the file header is there."""
    seed = BINARY_SEEDS[writer]
    k = int(cut * len(seed))
    res = check(tmp_path / "cut", seed[:k], format_of(writer))
    if isinstance(res, InputError):
        assert k < 200, res  # only a cut inside the file header is refused
        return
    stats = res.stats
    assert stats.frames <= len(FRAMES)
    if writer == "pcap":
        assert stats.frames == max(0, (k - 24) // PCAP_RECORD)
        assert stats.truncated == ((k - 24) % PCAP_RECORD != 0)
        assert stats.skipped == int(stats.truncated)
    elif writer == "pcapng":
        ends = _pcapng_block_ends(seed)
        assert stats.frames == sum(1 for e in ends[2:] if e <= k)  # after section, interface
        assert stats.truncated == (k not in ends)
    elif writer == "blf-plain":
        objects = [m.start() for m in re.finditer(b"LOBJ", seed)]
        whole = [o for o in objects if seed[o + 12:o + 16] == b"\x01\0\0\0"]
        assert stats.frames == sum(1 for o in whole if o + 48 <= k)
    elif writer == "mcap":
        assert stats.truncated == (k < len(seed) - 8)  # every cut before the footer's end
    if writer.startswith("blf") and k not in _blf_container_ends(seed):
        assert stats.truncated and stats.skipped == 1  # the object the cut went through


def _zstd(data: bytes) -> bytes:
    return zstandard.ZstdCompressor().compress(data)


COMPRESS: dict[str, Callable[[bytes], bytes]] = {"gz": gzip.compress, "xz": lzma.compress,
                                                 "zst": _zstd}


@pytest.mark.parametrize("suffix", sorted(COMPRESS))
@bounded(10)
@given(cut=st.floats(0.05, 0.95))
def test_compressed_log_cut_mid_stream_is_read_up_to_the_cut(tmp_path: Path, suffix: str,
                                                             cut: float) -> None:
    seed = b"".join(TEXT_WRITERS["candump"](FRAMES[i:] + FRAMES[:i]) for i in range(20))
    packed = COMPRESS[suffix](seed)
    res = check(tmp_path / f"cut.log.{suffix}", packed[:int(cut * len(packed))])
    if isinstance(res, InputError):  # not even the first block or line is whole
        assert "cannot decompress" in str(res), res
        return
    assert res.stats.truncated and res.stats.frames <= 20 * len(FRAMES)
    assert res.stats.skipped <= 1  # at most the line the damage cut


@pytest.mark.parametrize("suffix", sorted(COMPRESS))
def test_compressed_logs_concatenated_by_hand_are_read_whole(tmp_path: Path,
                                                             suffix: str) -> None:
    """`cat a.log.gz b.log.gz > ab.log.gz`: every member or frame is read."""
    data = COMPRESS[suffix](TEXT_SEEDS["candump"]) + COMPRESS[suffix](TEXT_SEEDS["candump"])
    res = check(tmp_path / f"ab.log.{suffix}", data)
    assert isinstance(res, InputResult)
    assert (res.stats.frames, res.stats.truncated) == (2 * len(FRAMES), False)


# --- corruption ---------------------------------------------------------------------------


@pytest.mark.parametrize("writer", sorted(SEEDS))
@bounded(25)
@given(edits=st.lists(EDIT, min_size=1, max_size=6))
def test_corrupted_bytes_give_a_report_or_an_input_error(tmp_path: Path, writer: str,
                                                        edits: list[tuple[float, str, bytes]]
                                                        ) -> None:
    data = apply_edits(SEEDS[writer], edits)
    assert_accounted(check(tmp_path / "log", data, format_of(writer)), data)
    assert_accounted(check(tmp_path / "log", data), data)  # sniffed: may be another format


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(25)
@given(which=st.floats(0, 1), junk=st.binary(max_size=200))
def test_a_corrupted_line_changes_only_that_line(tmp_path: Path, writer: str, which: float,
                                                 junk: bytes) -> None:
    seed = TEXT_SEEDS[writer]
    fmt = format_of(writer)
    records = record_lines(fmt, seed)
    target = records[20 + int(which * (len(records) - 21))]  # after the lines sniffing reads
    lines = seed.split(b"\n")
    lines[target - 1] = junk.replace(b"\n", b"")
    data = b"\n".join(lines)
    res = check(tmp_path / "log", data, fmt)
    assert_accounted(res, data)
    _, whole = columns(tmp_path / "whole", seed)
    _, damaged = columns(tmp_path / "log", data, fmt)
    before, after = frames_by_line(whole), frames_by_line(damaged)
    assert {k: v for k, v in after.items() if k != target} == {
        k: v for k, v in before.items() if k != target}


GARBAGE = st.binary(max_size=40).map(
    lambda b: b"zz" + bytes(c for c in b if c not in b" \t\n\r\x0b\x0c"))


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(12)
@given(picks=st.lists(st.floats(0, 1), min_size=1, max_size=5), garbage=GARBAGE,
       filler_only=st.booleans())
def test_corrupting_k_frame_lines_is_exactly_losing_k_frames(
        tmp_path: Path, writer: str, picks: list[float], garbage: bytes,
        filler_only: bool) -> None:
    """Differential: k unparseable frame lines lower `frames` by k and raise `skipped` by k;
    the findings are those of the log with the k lines left blank (same line numbers);
    when the k frames are frames no rule looks at, the findings are the original's."""
    seed = TEXT_SEEDS[writer]
    fmt = format_of(writer)
    records = record_lines(fmt, seed)
    frame_lines = [no for no, f in zip(records[-len(FRAMES):], FRAMES, strict=True)
                   if f.filler or not filler_only]
    chosen = sorted({frame_lines[int(p * (len(frame_lines) - 1))] for p in picks})
    k = len(chosen)
    lines = seed.split(b"\n")
    corrupted, blanked = list(lines), list(lines)
    for no in chosen:
        corrupted[no - 1] = garbage
        blanked[no - 1] = b""
    original = check(tmp_path / "original", seed, fmt)
    bad = check(tmp_path / "corrupted", b"\n".join(corrupted), fmt)
    blank = check(tmp_path / "blanked", b"\n".join(blanked), fmt)
    assert isinstance(original, InputResult) and isinstance(bad, InputResult)
    assert isinstance(blank, InputResult)
    assert bad.stats.frames == original.stats.frames - k == blank.stats.frames
    assert bad.stats.skipped == original.stats.skipped + k == blank.stats.skipped + k
    assert bad.stats.skipped_lines == chosen[:10]
    # the input rules (I003) report the corrupted lines; the network's findings are unchanged
    assert "I003" in [f.rule for f in bad.findings]
    assert network_findings(bad) == network_findings(blank)
    if filler_only:
        def without_index(res: InputResult) -> list[tuple[object, ...]]:
            return [f[:4] + f[5:] for f in network_findings(res)]

        assert without_index(bad) == without_index(original)


# --- line endings, BOM, timestamps --------------------------------------------------------


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(15)
@given(crlf=st.lists(st.booleans(), min_size=1), bom=st.booleans(), last_newline=st.booleans())
def test_crlf_lf_mixes_and_a_bom_change_nothing(tmp_path: Path, writer: str, crlf: list[bool],
                                                bom: bool, last_newline: bool) -> None:
    """A log copied through a Windows editor (some or all lines CRLF, a BOM, no final newline)
    gives the very same frames."""
    seed = TEXT_SEEDS[writer]
    lines = seed.split(b"\n")[:-1]
    ends = [b"\r\n" if crlf[i % len(crlf)] else b"\n" for i in range(len(lines))]
    if not last_newline:
        ends[-1] = b""
    data = (b"\xef\xbb\xbf" if bom else b"") + b"".join(
        line + end for line, end in zip(lines, ends, strict=True))
    _, whole = columns(tmp_path / "whole", seed)
    stats, mixed = columns(tmp_path / "mixed", data)
    assert stats.skipped == 0
    assert frames_by_line(mixed) == frames_by_line(whole)


MS = st.integers(0, 5000)


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(15)
@given(times=st.lists(MS, min_size=2, max_size=40))
def test_timestamps_that_go_backwards_or_repeat_are_kept_and_counted(
        tmp_path: Path, writer: str, times: list[int]) -> None:
    frames = [Frame(t / 1000, 0x701, b"\x05") for t in times]
    stats, cols = columns(tmp_path / "log", TEXT_WRITERS[writer](frames))
    assert stats.frames == len(times) and stats.skipped == 0
    assert stats.backwards_timestamps == sum(b < a for a, b in itertools.pairwise(times))
    offsets = np.round((cols["ts"] - cols["ts"][0]) * 1000).astype(np.int64)
    assert offsets.tolist() == [t - times[0] for t in times]  # file order, as written


# Where each format writes the timestamp of a frame line (group 1).
TIMESTAMP_FIELD = {
    "candump": rb"^\(([^)]*)\)",
    "asc": rb"^\s*(\S+)",
    "trc": rb"^\s*\d+\s+(\S+)",
    "candump-screen": rb"^\(([^)]*)\)",
    "csv": rb"^([^,]*)",
    "csv-savvycan": rb"^([^,]*)",
    "cl2000": rb"^([^;]*)",
}
NOT_A_NUMBER = st.sampled_from([b"", b"abc", b"1.2.3", b"--1", b"nan", b"NaN", b"inf",
                                b"-inf", b"1e999", b"0x10", b"12:00", b"\xd9\xa1\xd9\xa2",
                                b"\x00", b"1\x00", b"\xff", b"1,5,5"])


@pytest.mark.parametrize("writer", sorted(TEXT_WRITERS))
@bounded(12)
@given(stamp=NOT_A_NUMBER, which=st.floats(0, 1))
def test_a_timestamp_that_is_not_a_number_skips_its_line(tmp_path: Path, writer: str,
                                                         stamp: bytes, which: float) -> None:
    seed = TEXT_SEEDS[writer]
    fmt = format_of(writer)
    records = record_lines(fmt, seed)
    target = records[-len(FRAMES):][20 + int(which * (len(FRAMES) - 21))]
    lines = seed.split(b"\n")
    m = re.match(TIMESTAMP_FIELD[writer], lines[target - 1])
    assert m is not None
    lines[target - 1] = lines[target - 1][:m.start(1)] + stamp + lines[target - 1][m.end(1):]
    stats, _ = columns(tmp_path / "log", b"\n".join(lines), fmt)
    if writer == "asc" and stamp == b"":  # the columns shift: the channel `1` is the time,
        assert stats.frames == len(FRAMES) - 1  # and the rest a bad frame or another event
        assert stats.skipped + stats.ignored == 1 + 1  # (+ "Start of measurement")
        return
    assert (stats.frames, stats.skipped) == (len(FRAMES) - 1, 1)
    assert stats.skipped_lines == [target]


# --- structured garbage inside a valid container ------------------------------------------

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=6),
    max_leaves=20)
JSON_FIELDS = ["id", "can_id", "arbitration_id", "data", "dlc", "len", "is_rtr", "is_extended",
               "is_error", "is_fd", "channel", "header"]
CAN_JSON = st.dictionaries(st.sampled_from(JSON_FIELDS), JSON_VALUES, max_size=8)


@bounded(25)
@given(messages=st.lists(CAN_JSON, min_size=1, max_size=10))
def test_mcap_json_messages_with_any_values(tmp_path: Path, messages: list[dict[str, object]]
                                            ) -> None:
    """JSON CAN messages whose fields hold anything (Infinity, huge integers, nested lists,
    strings): each message is a frame or a skipped record."""
    first = {"id": 0x701, "data": [5]}  # decides that the topic is CAN
    payloads = [json.dumps(m).encode() for m in [first, *messages]]
    res = check(tmp_path / "log.mcap", mcap_json(payloads))
    assert isinstance(res, InputResult)
    assert res.stats.frames + res.stats.skipped == len(payloads)


# --- well-formed frames that make no sense ------------------------------------------------

CANOPEN_IDS = st.one_of(
    st.sampled_from([0x000, 0x001, 0x080, 0x100]),
    st.integers(1, 127).flatmap(lambda n: st.sampled_from(
        [0x700 + n, 0x180 + n, 0x200 + n, 0x580 + n, 0x600 + n, 0x080 + n])),
    st.integers(0, 0x7FF))
CANOPEN_FRAME = st.tuples(
    st.one_of(st.floats(-1e6, 1e12, allow_nan=False), st.sampled_from([0.0, 1e-9, 1e15])),
    CANOPEN_IDS, st.binary(max_size=8), st.booleans())


@bounded(60)
@given(frames=st.lists(CANOPEN_FRAME, min_size=1, max_size=60))
def test_any_sequence_of_canopen_frames_gives_a_report(tmp_path: Path,
                                                       frames: list[tuple[float, int, bytes,
                                                                          bool]]) -> None:
    """Boot-ups, heartbeats, NMT commands, guarding requests, SDOs and PDOs in any order, at
    any times (backwards, equal, far apart), with any payload: the rules never crash."""
    lines = [f"({t:.6f}) can0 {i:03X}#" + ("R" if rtr else data.hex()) + "\n"
             for t, i, data, rtr in frames]
    res = check(tmp_path / "log", "".join(lines).encode(), "candump")
    # a stamp candump never writes (negative, 10^12 s or more) is a skipped record (issue 24)
    stamps = [f"{t:.6f}" for t, _i, _data, _rtr in frames]
    kept = sum(not s.startswith("-") and float(s) < MAX_TIMESTAMP_S for s in stamps)
    assert isinstance(res, InputResult) and res.stats.frames == kept
    assert res.stats.skipped == len(frames) - kept

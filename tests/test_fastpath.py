"""The vectorised text readers against the per-line reference path (NMTCHECK_REFERENCE=1).

Both paths must give the same frames (every column), the same input statistics
(skips with their line numbers, ignored, dropped, channels…) and so the same
findings: on the samples, on the third-party corpus, and on fuzzed lines that
sit next to the fast path's common shape (so that every near miss is handed to
the reference parser, not misread). `FUZZ_SEEDS=400` fuzzes longer than CI does.
"""

from __future__ import annotations

import dataclasses
import os
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import CORPUS, REPO, SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.readers import InputStats, blocks, open_input
from nmtcheck.readers.blocks import REFERENCE_ENV
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.settings.profiles import load_profile

THIRD = CORPUS / "third_party"
TEXT_LOGS = sorted(SAMPLES.glob("*.log")) + sorted(SAMPLES.glob("*.asc")) + (
    sorted(p for p in THIRD.rglob("*") if p.name.endswith((".log", ".asc", ".asc.gz"))
           or p.name in ("candump.gz", "gmlan_trace.candump.gz")) if THIRD.is_dir() else [])


def _read(path: Path, reference: bool, mp: pytest.MonkeyPatch,
          fmt: str | None = None) -> tuple[InputStats, list[FrameBatch]]:
    with mp.context() as m:
        if reference:
            m.setenv(REFERENCE_ENV, "1")
        else:
            m.delenv(REFERENCE_ENV, raising=False)
        opened = open_input(str(path), fmt)
        return opened.stats, list(opened.batches)


def assert_same_reading(path: Path, mp: pytest.MonkeyPatch, fmt: str | None = None) -> None:
    fast_stats, fast = _read(path, False, mp, fmt)
    ref_stats, ref = _read(path, True, mp, fmt)
    assert dataclasses.asdict(fast_stats) == dataclasses.asdict(ref_stats)
    assert [len(b) for b in fast] == [len(b) for b in ref]  # same batch boundaries
    for name in (f.name for f in dataclasses.fields(FrameBatch)):
        for a, b in zip(fast, ref, strict=True):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.mark.parametrize("path", TEXT_LOGS, ids=lambda p: p.name)
def test_samples_and_corpus_read_identically(path: Path, monkeypatch: pytest.MonkeyPatch
                                             ) -> None:
    assert_same_reading(path, monkeypatch)


@pytest.mark.parametrize("path", TEXT_LOGS, ids=lambda p: p.name)
def test_samples_and_corpus_give_identical_findings(path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])

    def findings(reference: bool) -> list[tuple[object, ...]]:
        with monkeypatch.context() as m:
            if reference:
                m.setenv(REFERENCE_ENV, "1")
            res = check_input(str(path), 0, profile, rules)
            return [dataclasses.astuple(f) for f in res.findings] + [
                (iv.state, iv.start, iv.end, iv.source) for n in res.nodes() for iv in n.intervals]

    assert findings(False) == findings(True)


# --- fuzzing around the candump fast path's shape ----------------------------------------

_CHARS = "()#. \t\r0123456789abcdefABCDEFRTxg_-+e\x0b\xff"


def _candump_line(rnd: random.Random) -> str:
    int_digits = rnd.choice((1, 1, 3, 8, 9, 10, 10, 10, 12, 13))
    frac_digits = rnd.choice((0, 1, 3, 6, 6, 6, 8, 9, 10))
    ts = "".join(rnd.choice("0123456789") for _ in range(int_digits))
    if frac_digits:
        ts += "." + "".join(rnd.choice("0123456789") for _ in range(frac_digits))
    iface = rnd.choice(("can0", "can0", "vcan12", "c", "slcan0", "can_with_long_nm",
                        "a17charsinterface"))
    cid = "".join(rnd.choice("0123456789abcdefABCDEF") for _ in range(rnd.choice((3, 3, 3, 8))))
    data = "".join(rnd.choice("0123456789abcdefABCDEF")
                   for _ in range(rnd.choice((0, 2, 4, 8, 16, 16, 15, 18))))
    if rnd.random() < 0.2:  # a remote frame (node guarding), lengths good and bad
        data = rnd.choice(("R", "R", "r", "R0", "R1", "R1", "R8", "R9", "RA", "R12", "R8_9",
                           "R_", "RR"))
    suffix = rnd.choice(("", "", " R", " T", " X", "  R"))
    return f"({ts}) {iface} {cid}#{data}{suffix}"


def _mutate(line: str, rnd: random.Random) -> str:
    chars = list(line)
    for _ in range(rnd.choice((1, 1, 2))):
        i = rnd.randrange(len(chars) + 1)
        op = rnd.random()
        if op < 0.4 and i < len(chars):
            chars[i] = rnd.choice(_CHARS)
        elif op < 0.7:
            chars.insert(i, rnd.choice(_CHARS))
        elif i < len(chars):
            del chars[i]
    return "".join(chars)


@pytest.mark.parametrize("seed", range(int(os.environ.get("FUZZ_SEEDS", "4"))))
def test_fuzzed_candump_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    rnd = random.Random(seed)
    lines = []
    for _ in range(3000):
        line = _candump_line(rnd)
        if rnd.random() < 0.3:
            line = _mutate(line, rnd)
        lines.append(line + rnd.choice(("\n", "\n", "\r\n")))
    lines += ["\n", "DROPCOUNT: dropped 3\n", "   \n", "(1.5) can0 123#R\n",
              "(1.5) can9 12345678#00"]
    path = tmp_path / "fuzz.log"
    path.write_bytes("".join(lines).encode("latin-1"))
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 4096)  # many blocks: lines cut at block ends
    assert_same_reading(path, monkeypatch, "candump")


# --- fuzzing around the ASC fast path's shape --------------------------------------------

_ASC_HEADERS = ["date Tue Nov 14 22:13:20.000 2023", "base hex  timestamps absolute",
                "internal events logged", "// version 13.0.0",
                "Begin Triggerblock Tue Nov 14 22:13:20.000 2023",
                "   0.000000 Start of measurement"]


def _asc_line(rnd: random.Random, t: float) -> str:
    ts = f"{t:{rnd.choice(('11', '11', '11', '9', '1', '14'))}.{rnd.choice((6, 6, 6, 3, 9))}f}"
    chan = rnd.choice(("1", "1", "2", "12", "0"))
    cid = f"{rnd.choice((0x181, 0x701, 0x5, 0x7FF, 0x800, 0x1ABCDEF)):X}"
    if rnd.random() < 0.05:
        cid += "x"
    dlc = rnd.choice((0, 1, 2, 8, 8, 8, 9, 12))
    data = " ".join(f"{rnd.randrange(256):02X}" for _ in range(min(dlc, 8)))
    kind = rnd.choice(("d", "d", "d", "D", "r"))
    direction = rnd.choice(("Rx", "Rx", "Tx", "TxRq"))
    tail = rnd.choice(("", "", "  Length = 240000 BitCount = 120 ID = 385", " x"))
    if kind == "r" and rnd.random() < 0.5:  # a remote frame without its length, as CANoe
        return f"{ts} {chan}  {cid:<15} {direction}   " + rnd.choice(("r", "R", "r ", "r  1",
                                                                      "r\r", "r 1", "r x"))
    return f"{ts} {chan}  {cid:<15} {direction}   {kind} {dlc:x} {data}{tail}".rstrip(" ") \
        if rnd.random() < 0.9 else f"{ts} {chan}  {cid:<15} {direction}   {kind} {dlc:x} {data}"


@pytest.mark.parametrize("seed", range(int(os.environ.get("FUZZ_SEEDS", "4"))))
def test_fuzzed_asc_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    rnd = random.Random(seed)
    lines = [h + "\n" for h in _ASC_HEADERS]
    t = 0.0
    for _ in range(3000):
        t += rnd.choice((0.0, 0.000123, 0.01, 3.5, 250.0))
        line = _asc_line(rnd, t)
        if rnd.random() < 0.3:
            line = _mutate(line, rnd)
        if rnd.random() < 0.003:  # the header can change the number base or the time mode
            line = rnd.choice(("base dec  timestamps absolute", "base hex  timestamps relative",
                               "base hex  timestamps absolute", "Begin Triggerblock",
                               "End TriggerBlock"))
        lines.append(line + rnd.choice(("\n", "\n", "\r\n")))
    path = tmp_path / "fuzz.asc"
    path.write_bytes("".join(lines).encode("latin-1"))
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 8192)
    assert_same_reading(path, monkeypatch, "asc")


# --- fuzzing around the candump screen output's fast path ---------------------------------


def _screen_line(rnd: random.Random, mode: str, t: float) -> str:
    """A line as candump prints it (` (%010ld.%06ld)  %*s  %03X   [%d]  %02X …`), with the
    variants of its options: `-x`, `-a`, `-c`, CAN FD, 29-bit IDs, remote and error frames."""
    stamp = {"bare": "", "ta": f"({t:017.6f}) ", "tz": f"({t % 1000:010.6f}) "}[mode]
    iface = rnd.choice(("can0", "can0", "can0", "vcan12", "c", "can_with_long_nm", "a@b",
                        "DROPCOUNTER0"))
    cid = rnd.choice(("701", "000", "181", "7FF", "1abcDEF0", "20000004", "6a2"))
    dlc = rnd.choice((0, 1, 1, 2, 4, 8, 8, 9))
    data = [f"{rnd.randrange(256):02X}" for _ in range(min(dlc, 8))]
    body = f" [{dlc}] " + "".join(f" {b}" for b in data)
    r = rnd.random()
    if r < 0.05:
        body = f" [{rnd.choice((0, 1, 8))}]  remote request"
    elif r < 0.08:
        body = "[12] " + "".join(" 11" for _ in range(12))
    elif r < 0.10:
        body += "   ERRORFRAME"
    elif r < 0.13:
        body += "   '" + "." * len(data) + "'"
    elif r < 0.15:
        body += rnd.choice(("  # boot-up", "  <-- here", " x", "   "))
    flags = rnd.choice(("", "", "", "  RX - -", "  TX B E"))
    line = f" {stamp} {iface}{flags}  {cid}  {body}"
    if rnd.random() < 0.03:
        line = f"\x1b[1m\x1b[34m{line}\x1b[0m"
    return line


@pytest.mark.parametrize("mode", ["bare", "ta", "tz"])
@pytest.mark.parametrize("seed", range(int(os.environ.get("FUZZ_SEEDS", "4"))))
def test_fuzzed_screen_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int,
                             mode: str) -> None:
    rnd = random.Random(seed)
    lines = [_screen_line(rnd, mode, 1700000000.0) for _ in range(5)]  # a clean start
    t = 1700000000.0
    for _ in range(3000):
        t += rnd.choice((0.0, 0.000123, 0.01, 3.5))
        line = _screen_line(rnd, mode, t)
        if rnd.random() < 0.3:
            line = _mutate(line, rnd)
        if rnd.random() < 0.01:
            line = rnd.choice(("DROPCOUNT: dropped 3 frames", "\tcontroller-problem{rx}",
                               "$ candump can0", "", "  ", "# note", "..."))
        lines.append(line + rnd.choice(("\n", "\n", "\r\n")))
    path = tmp_path / "fuzz.txt"
    path.write_bytes("".join(lines).encode("latin-1"))
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 4096)  # many blocks: lines cut at block ends
    _stats, batches = _read(path, False, monkeypatch, "candump-screen")
    assert sum(len(b) for b in batches) > 1000  # most lines are frames: the fast path ran
    assert_same_reading(path, monkeypatch, "candump-screen")


def test_screen_output_takes_the_fast_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                           ) -> None:
    """`candump can0 > dump.txt` (no timestamps) and `-ta`: their lines are parsed a block at
    a time, not one by one (1 M frames: 0.65 s against 6.8 s), with the same result."""
    from nmtcheck.readers import candump_screen

    calls: list[int] = []
    parse = candump_screen._LineParser.parse

    def counted(self: Any, *args: Any) -> Any:
        calls.append(1)
        return parse(self, *args)

    frames = [(0x701, [0x7F]), (0x000, [0x01, 0x00]), (0x181, list(range(8))), (0x080, [])]
    for stamp in ("", "(1700000000.100000) "):
        text = "".join(f" {stamp} can0  {i:03X}   [{len(d)}] " + "".join(f" {b:02X}" for b in d)
                       + "\n" for i, d in frames * 50)
        path = tmp_path / "screen.txt"
        path.write_text(text)
        calls.clear()
        with monkeypatch.context() as m:
            m.setattr(candump_screen._LineParser, "parse", counted)
            _stats, batches = _read(path, False, monkeypatch, "candump-screen")
        assert sum(len(b) for b in batches) == 200 and calls == []
        assert_same_reading(path, monkeypatch, "candump-screen")


@pytest.mark.parametrize("block_bytes", [40, 4096])
def test_screen_error_frame_explanation_ends_at_a_fast_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, block_bytes: int) -> None:
    """`-e` explains an error frame on the tab-indented lines right after it. A frame line
    in between (parsed by the fast path, never seen by the line parser) ends that: a damaged
    tab-indented line after it is a skipped record, also across a block's end."""
    lines = ["  can0  701   [1]  7F",
             "  can0  20000004   [8]  00 04 00 00 00 00 00 00   ERRORFRAME",
             "\tcontroller-problem{rx-error-warning}", "  can0  701   [1]  7F",
             "\tcontroller-problem{rx-error-warning}", "  can0  701   [1]  7F"]
    path = tmp_path / "screen.txt"
    path.write_text("".join(line + "\n" for line in lines))
    monkeypatch.setattr(blocks, "BLOCK_BYTES", block_bytes)
    stats, _ = _read(path, False, monkeypatch, "candump-screen")
    assert (stats.frames, stats.skipped, stats.skipped_lines) == (4, 1, [5])
    assert_same_reading(path, monkeypatch, "candump-screen")


# --- several logs at once, and what stderr shows ------------------------------------------


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], capture_output=True,
                          text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))


def test_jobs_give_the_same_report_in_the_same_order() -> None:
    logs = [str(SAMPLES / n) for n in ("healthy.log", "guard_toggle.asc", "pdo_preop.log")]
    serial = _cli("check", *logs, "--format", "json", "--fail-on", "never")
    parallel = _cli("check", "-j", "2", *logs, "--format", "json", "--fail-on", "never")
    assert serial.returncode == parallel.returncode == 0
    assert parallel.stdout == serial.stdout
    assert parallel.stderr == ""  # no progress bar when stderr is not a terminal


def test_jobs_report_every_failing_input_in_order(tmp_path: Path) -> None:
    # each unreadable input is named, in order, and the good one is still reported (SPEC §4)
    bad = tmp_path / "empty.log"
    bad.write_bytes(b"")
    res = _cli("check", "-j", "2", str(SAMPLES / "healthy.log"), str(bad), str(tmp_path / "x"))
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"nmtcheck: {bad}: empty file: no records to check",
        f"nmtcheck: {tmp_path / 'x'}: no such file"]
    assert "healthy.log (candump): 351 frames" in res.stdout


@pytest.mark.parametrize("block_bytes", [7, 64, 1000])
def test_blocks_smaller_than_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   block_bytes: int) -> None:
    """Lines cut by reads of any size (a line longer than a block is carried over)."""
    monkeypatch.setattr(blocks, "BLOCK_BYTES", block_bytes)
    for name in ("healthy.log", "healthy.asc"):
        text = (SAMPLES / name).read_bytes()
        path = tmp_path / name
        path.write_bytes(text[:4000].rstrip(b"\n"))  # and a last line without newline
        assert_same_reading(path, monkeypatch)


def test_overlong_lines_are_one_skipped_record_each(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Lines of 1 MiB or more, inside a block or longer than one, as Source.lines() has them."""
    mib = 1 << 20
    good = "(1700000000.000100) can0 701#05\n"
    path = tmp_path / "long.log"
    path.write_bytes((good * 3 + "7" * (mib - 1) + "\n" + good + "7 " * (mib // 2) + "\n"
                      + good + "x" * (3 * mib) + "\r\n" + good + "y" * (mib + 5)).encode())
    assert_same_reading(path, monkeypatch)
    stats, _ = _read(path, False, monkeypatch)
    assert (stats.frames, stats.skipped, stats.skipped_lines) == (6, 4, [4, 6, 8, 10])


def test_remote_frames_take_the_fast_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                          ) -> None:
    # node guarding: every other frame a remote request; line by line it took 4x as long
    from nmtcheck.readers import candump

    lines = [f"({1700000000 + i // 2}.{i % 2}00000) can0 70{i % 7 + 1}#"
             + ("R" if i % 4 == 0 else "R1" if i % 4 == 2 else "05" if i % 8 < 4 else "85")
             for i in range(2000)]
    lines += ["(1700002000.000000) can0 1ABCDEF5#r", "(1700002000.100000) can1 123#R8"]
    path = tmp_path / "guarding.log"
    path.write_text("\n".join(lines) + "\n")
    assert_same_reading(path, monkeypatch, "candump")

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError(f"a line went to the per-line parser: {args[0]!r}")

    monkeypatch.setattr(candump, "_parse_line", refuse)
    batches = _read(path, False, monkeypatch, "candump")[1]
    rtr = np.concatenate([b.rtr for b in batches])
    dlc = np.concatenate([b.dlc for b in batches])
    assert int(rtr.sum()) == 1002 and dlc[:4].tolist() == [0, 1, 1, 1]
    assert dlc[-1] == 8 and bool(rtr[-1]) and bool(np.concatenate([b.ext for b in batches])[-2])


def test_asc_remote_frames_take_the_fast_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                              ) -> None:
    # CANoe writes a remote request as `r` (and maybe its length): node guarding
    from nmtcheck.readers import asc

    lines = [*_ASC_HEADERS]
    for i in range(2000):
        t = i * 0.05
        request = "r" if i % 3 else "r 1"
        lines.append(f"{t:11.6f} 1  {0x701 + i % 7:<15X} Rx   {request}")
        lines.append(f"{t + 0.002:11.6f} 1  {0x701 + i % 7:<15X} Rx   d 1 "
                     f"{(i // 7 % 2) << 7 | 5:02X}")
    lines.append("End TriggerBlock")
    path = tmp_path / "guarding.asc"
    path.write_text("\n".join(lines) + "\n")
    assert_same_reading(path, monkeypatch, "asc")
    per_line = asc._parse_line
    calls: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return per_line(*args, **kwargs)

    monkeypatch.setattr(asc, "_parse_line", counted)
    batches = _read(path, False, monkeypatch, "asc")[1]
    assert len(calls) <= len(_ASC_HEADERS) + 1  # the header and footer lines only
    rtr = np.concatenate([b.rtr for b in batches])
    dlc = np.concatenate([b.dlc for b in batches])
    assert int(rtr.sum()) == 2000 and dlc[:4].tolist() == [1, 1, 0, 1]

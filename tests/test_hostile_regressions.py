"""Every crash the hostile-input tests and the fuzzers found, as the exact input that caused
it: each must now give a report (the damaged record skipped) or a one-line input error.

Bugs in files another developer owns are kept as strict xfails naming the bug, so the test
turns green (and the xfail must go) when they are fixed.
"""

from __future__ import annotations

import gzip
import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
from hostile_logs import BINARY_WRITERS, TEXT_WRITERS, mcap_json, network_frames

from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import InputError
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])
FRAMES = network_frames()


def check(tmp_path: Path, data: bytes, name: str = "log") -> InputResult:
    path = tmp_path / name
    path.write_bytes(data)
    return check_input(str(path), 0, PROFILE, RULES)


def with_line(writer: str, line: bytes) -> bytes:
    """A valid log of the format with one more record line at the end."""
    return TEXT_WRITERS[writer](FRAMES) + line + b"\n"


def assert_one_more_skipped(res: InputResult) -> None:
    assert (res.stats.frames, res.stats.skipped) == (len(FRAMES), 1)


# --- fixed: numbers that Python's int()/float() take but a log field never holds ----------


@pytest.mark.parametrize("writer, line", [
    # OverflowError: Python integer -1793 out of bounds for uint32 (a negative CAN-ID)
    ("trc", b"    999       3000.000 DT 1     -701 Rx - 1  05"),
    ("cl2000", b"01T022235000;0;-701;05"),
    ("csv-savvycan", b"1700000003000000,-0000701,false,Rx,0,1,05,00,00,00,00,00,00,00,"),
    ("csv", b"1700000003.0,-0x701,0,0,0,1,BQ=="),
    ("candump-screen", b"(1700000003.000000)  can0  -01   [1]  05"),
    # a negative DLC or lost count was taken as a count
    ("csv", b"1700000003.0,0x701,0,0,0,-1,BQ=="),
    ("csv-savvycan", b"1700000003000000,00000701,false,Rx,0,-1,05,00,00,00,00,00,00,00,"),
    # OverflowError: integer division result too large for a float (a 400-digit time)
    ("csv-savvycan", b"1" + b"0" * 400 + b",00000701,false,Rx,0,1,05,00,00,00,00,00,00,00,"),
    # ValueError: month must be in 1..12 (candump -tA stamp with month 13)
    ("candump-screen", b"(2023-13-01 00:00:00.000000)  can0  701   [1]  05"),
    # an infinite time: 400 digits before the point
    ("candump-screen", b"(" + b"9" * 400 + b".000000)  can0  701   [1]  05"),
    # `1_0` and `+5` are numbers to int(), not to a logger
    ("trc", b"    999       3000.000 DT 1     07_1 Rx - 1  05"),
    ("cl2000", b"01T022235000;0;+701;05"),
])
def test_number_fields_that_only_python_calls_numbers(tmp_path: Path, writer: str,
                                                      line: bytes) -> None:
    assert_one_more_skipped(check(tmp_path, with_line(writer, line)))


def test_a_dropcount_of_5000_digits_in_screen_output(tmp_path: Path) -> None:
    """ValueError: Exceeds the limit (4300 digits) for integer string conversion."""
    res = check(tmp_path, with_line("candump-screen", b"DROPCOUNT: dropped " + b"9" * 5000))
    assert_one_more_skipped(res)
    assert res.stats.dropped == 0


def test_a_dropcount_of_5000_digits_in_a_candump_log(tmp_path: Path) -> None:
    res = check(tmp_path, with_line("candump", b"DROPCOUNT: dropped " + b"9" * 5000))
    assert_one_more_skipped(res)


# --- fixed: binary structures whose sizes lie ---------------------------------------------


def _pcapng_with_interface(body: bytes) -> bytes:
    """A pcapng file whose interface block has `body`, then the network's packets."""
    whole = BINARY_WRITERS["pcapng"](FRAMES)
    shb_end = int.from_bytes(whole[4:8], "little")
    idb_end = shb_end + int.from_bytes(whole[shb_end + 4:shb_end + 8], "little")
    body += b"\0" * (-len(body) % 4)
    idb = struct.pack("<II", 1, len(body) + 12) + body + struct.pack("<I", len(body) + 12)
    return whole[:shb_end] + idb + whole[idb_end:]


@pytest.mark.parametrize("body, usable, why", [
    (b"", False, "struct.error: an interface block without its link type"),
    (struct.pack("<HHI", 227, 0, 0) + struct.pack("<HH", 9, 40), True,
     "IndexError: an if_tsresol option longer than the block"),
    (struct.pack("<HHI", 227, 0, 0) + struct.pack("<HH", 14, 8) + b"\1\2", True,
     "struct.error: an if_tsoffset option cut short"),
    (struct.pack("<HHI", 227, 0, 0) + struct.pack("<HHB3x", 9, 1, 0x7F), False,
     "OverflowError: if_tsresol 10^-127 s does not fit uint64 arithmetic"),
])
def test_pcapng_interface_block_that_lies(tmp_path: Path, body: bytes, usable: bool,
                                          why: str) -> None:
    """An option that runs past its block ends the options (the link type is known); an
    interface without a link type or with an impossible resolution is damaged: its packets
    are skipped."""
    res = check(tmp_path, _pcapng_with_interface(body))
    if usable:
        assert (res.stats.frames, res.stats.skipped) == (len(FRAMES), 0), why
    else:
        assert (res.stats.frames, res.stats.skipped) == (0, len(FRAMES) + 1), why


def test_blf_file_header_cut_after_its_first_72_bytes(tmp_path: Path) -> None:
    """Was a report of 0 frames that said nothing about the damage."""
    with pytest.raises(InputError, match="BLF file header is truncated"):
        check(tmp_path, BINARY_WRITERS["blf"](FRAMES)[:100])


def test_blf_header_size_of_4_gib_is_not_read_in_one_piece(tmp_path: Path) -> None:
    whole = bytearray(BINARY_WRITERS["blf"](FRAMES))
    whole[4:8] = struct.pack("<L", 0xFFFFFFF0)
    with pytest.raises(InputError, match="BLF file header is truncated"):
        check(tmp_path, bytes(whole))


def test_mcap_record_claiming_4_gib_is_read_in_pieces(tmp_path: Path) -> None:
    """One read() of the claimed length allocated 4 GiB up front: MemoryError under a limit."""
    whole = BINARY_WRITERS["mcap"](FRAMES)
    cut = whole.index(b"\x06", 8 + 9 + struct.unpack_from("<Q", whole, 9)[0])  # after header
    damaged = whole[:cut] + b"\x06" + struct.pack("<Q", (4 << 30) - 1) + whole[cut + 9:]
    (tmp_path / "big.mcap").write_bytes(damaged)
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30));"
            "from nmtcheck.cli.main import main; sys.argv = ['nmtcheck', 'check', '--format', "
            "'json', 'big.mcap']; main()")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120,
                         env={"PYTHONPATH": str(Path(__file__).resolve().parent.parent),
                              "OPENBLAS_NUM_THREADS": "1"})
    assert res.stderr == "" and res.returncode in (0, 1), res.stderr
    report = json.loads(res.stdout)
    entry = report["inputs"][0]
    assert entry["truncated"] and entry["skipped"] == 1
    rules = {f["rule"] for f in report["findings"]}
    assert {"I002", "I003"} <= rules  # reported as truncated and skipped (SPEC §3 I-rules)
    assert res.returncode == (1 if "I001" in rules else 0)


@pytest.mark.parametrize("message", [
    b'{"id": Infinity, "data": [5]}',  # OverflowError: cannot convert float infinity to int
    b'{"id": 1793, "data": [Infinity]}',
    b'{"id": 1793, "data": [5], "header": {"stamp": {"sec": 1' + b"0" * 400 + b"}}}",
    b'{"id": 1793, "data": [5], "header": {"stamp": {"nanosec": 1' + b"0" * 400 + b"}}}",
])
def test_mcap_json_values_beyond_any_range(tmp_path: Path, message: bytes) -> None:
    res = check(tmp_path, mcap_json([b'{"id": 1793, "data": [5]}', message]), "log.mcap")
    assert (res.stats.frames, res.stats.skipped) == (1, 1)


def test_a_damaged_mcap_schema_prints_nothing_on_stderr(tmp_path: Path) -> None:
    """mcap_ros2's schema parser printed 'Error processing …' lines on stderr."""
    whole = BINARY_WRITERS["mcap"](FRAMES)
    damaged = whole.replace(b"bool is_rtr", b"bool is_   ", 1)
    (tmp_path / "x.mcap").write_bytes(damaged)
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "x.mcap", "--format",
                          "json"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(Path(__file__).resolve().parent.parent)})
    assert res.returncode == 1 and res.stderr == ""  # I001: nothing could be checked
    report = json.loads(res.stdout)
    assert report["inputs"][0]["skipped"] == len(FRAMES)
    assert {f["rule"] for f in report["findings"]} == {"I001", "I003"}


def test_small_gzip_cut_mid_stream(tmp_path: Path) -> None:
    """The whole file is one read of the decompressor: a read() that met the cut lost all the
    data decompressed before it (an input error instead of the frames before the cut)."""
    packed = gzip.compress(TEXT_WRITERS["candump"](FRAMES) * 50)
    res = check(tmp_path, packed[:len(packed) // 2], "cut.log.gz")
    assert res.stats.truncated and res.stats.frames > len(FRAMES)


def _resets_log(resets: int) -> bytes:
    """A master resetting node 1 every 0.5 s; the node boots and heartbeats every 10 ms."""
    lines = []
    for k in range(resets):
        t = 1000.0 + 0.5 * k
        lines.append(f"({t:.6f}) can0 000#8201\n({t + 0.001:.6f}) can0 701#00\n")
        lines += [f"({t + 0.01 * i:.6f}) can0 701#05\n" for i in range(1, 50)]
    return "".join(lines).encode()


def test_a_node_reset_1500_times_is_checked_in_linear_time(tmp_path: Path) -> None:
    (tmp_path / "resets.log").write_bytes(_resets_log(1500))  # 76,500 frames: ~1 s if linear
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "resets.log", "-q"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=6,
                         env={"PYTHONPATH": str(Path(__file__).resolve().parent.parent)})
    assert res.returncode == 0 and "PASS: 0 errors," in res.stdout, res.stderr


def test_zstd_log_cut_mid_stream_is_reported_truncated(tmp_path: Path) -> None:
    """zstandard's stream reader ends silently where a cut file ends: half a log was read
    as if it were the whole log."""
    import random

    import zstandard

    rnd = random.Random(7)
    text = b"".join(b"(%d.000000) can0 181#%s\n" % (i, rnd.randbytes(8).hex().encode())
                    for i in range(20000))
    packed = zstandard.ZstdCompressor().compress(text)
    res = check(tmp_path, packed[:len(packed) // 2], "cut.log.zst")
    assert res.stats.truncated and 1000 < res.stats.frames < 20000


@pytest.mark.parametrize("extra", [1, 3])
def test_blf_cut_inside_the_signature_of_the_next_object(tmp_path: Path, extra: int) -> None:
    """`L` or `LOB` after the last whole container: was one skipped record, not truncated."""
    whole = BINARY_WRITERS["blf"](FRAMES)
    last = whole.rindex(b"LOBJ")
    res = check(tmp_path, whole[:last + extra])
    assert res.stats.truncated and res.stats.skipped == 1 and res.stats.frames < len(FRAMES)


def test_gzip_cut_inside_the_first_line_names_the_damage(tmp_path: Path) -> None:
    """Was 'unknown log format': the few bytes that could be decompressed tell no format."""
    packed = gzip.compress(TEXT_WRITERS["candump"](FRAMES))
    cut = next(k for k in range(len(packed))  # the first cut that leaves part of line 1
               if zlib.decompressobj(wbits=31).decompress(packed[:k]))
    with pytest.raises(InputError, match=r"cannot decompress \(gzip\) beyond its first"):
        check(tmp_path, packed[:cut], "cut.log.gz")

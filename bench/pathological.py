"""Pathological logs: nmtcheck's time and peak memory when every frame is an event.

    python bench/pathological.py --sizes 1M                     # every kind and output
    python bench/pathological.py --sizes 1M,5M --kinds clean,flapping --outputs json
    python bench/pathological.py --nmtcheck /tmp/venv-patho/bin/nmtcheck --write --label Before

Writes candump logs (vectorised, like bench/generate.py) under --data (default
/tmp/nmtcheck-patho, kept between runs) of these kinds, each exactly N frames:

- clean: the speed benchmark's realistic traffic (bench/traffic.py), a few findings;
- flapping: heartbeats of 16 nodes (20 ms), every heartbeat reports another state
  than the node's last one (05h, 7Fh, 04h, ...): a state change (S005) per frame;
- commands: every NMT command specifier (01h, 02h, 80h, 81h, 82h) to every node-ID
  0-127 in turn on 000h, one frame in five a heartbeat of one of 16 nodes;
- findings: 000h frames of every DLC but 2, in turn: a malformed NMT command
  (C002) per frame, each its own finding because neighbours differ in DLC;
- nodes127: heartbeats (05h) of 127 nodes every 100 ms, nothing else;
- emcy: EMCYs of 16 nodes, 100 us apart, error code and register cycling, one frame
  in five a heartbeat: a node event per frame;
- sdo: SDO expedited downloads to 1017h (producer heartbeat time) of 16 nodes and
  their confirmations, 100 us apart, one frame in five a heartbeat: a configuration
  write per two frames;
- aborts: SDO aborts (1017h, code 06090011h) of 16 servers, 100 us apart, one frame in
  five a heartbeat: a node event per frame;
- channels (issue 24): N/2 interfaces `c0`, `c1`, ... of two frames each (a heartbeat
  705#00, then a TPDO 185#01 of node 5 on every interface), 1 ms apart: the channel
  dimension (40,000 channels at N = 80,000);
- chanbeats: N/4 interfaces of a boot-up 705#00 and three heartbeats 705#05, 100 ms
  apart (40,000 channels at N = 160,000): channels whose node sends heartbeats;
- canids: every 11-bit CAN-ID 000h..7FFh in turn, one data byte, 100 us apart: the
  CAN-ID dimension (NMT, SYNC, EMCY, PDOs, SDOs, heartbeats of every node 1..127);
- extended: 29-bit J1939 frames (18FEF100h + source address, 8 bytes) with one
  heartbeat in five, 100 us apart: the vectorised reader's 8-digit IDs;
- errorframes: error frames (`20000004#...`) with one heartbeat in five: likewise;
- boots (issue 22): CiA 302-2 boot processes of 16 nodes in turn, every one ok;
- bootfail (issue 22): the same, but each node refuses the 1017h download (SDO abort
  06010002h, read-only): a failed process and a P003 finding per 8 frames;
- jitter (issue 39): heartbeats (05h) of 8 nodes every 10 ms, each +-0.5 ms (uniform),
  in time order: real heartbeats jitter, and their runs must compact all the same;
- wander (issue 39): the same heartbeats in bus order, each node's stamps off by up to
  0.1 s either way (its clock wanders, a sine of a minute or so): up to 0.2 s out of order;
- restarts (issue 39): a block of 4,000 frames (heartbeats of 4 nodes every 1 ms) again
  and again: time goes back to the start every second, a capture per block;
- guarded: node guarding of 16 nodes every 100 ms (remote request 700h+N, the answer
  05h with its toggle bit alternating 2 ms later), nothing else: half remote frames,
  and the error-control stream of networks that guard instead of beating.

Then runs `NMTCHECK check LOG --format text` (stdout to /dev/null) with one report
file per run (`-o report.json`, ... ; `text` alone writes none) through a small
launcher that applies a memory limit (RLIMIT_AS) and a timeout to the whole process
group, and measures wall time, the peak of the summed RSS of the process tree
(sampled from /proc every 20 ms) and the largest ru_maxrss of any one process
(RUSAGE_CHILDREN). Sizes above 1 M are run for a kind and output only when its 1 M
run succeeded within --big-if-1m-under seconds. Prints a Markdown table; --write
puts it into bench/PATHOLOGICAL.md (--append adds a section instead).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shlex
import subprocess
import sys
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from generate import candump_lines  # noqa: E402
from run import machine, parse_size  # noqa: E402
from traffic import CHUNK_FRAMES, T0_US, Frames, traffic  # noqa: E402

KINDS = ("clean", "flapping", "commands", "findings", "nodes127", "emcy", "sdo", "aborts",
         "channels", "chanbeats", "canids", "extended", "errorframes", "boots", "bootfail",
         "guarded", "keepalive", "jitter", "wander", "restarts")
OUTPUTS = ("text", "json", "html", "sarif", "csv")
COMMANDS = np.asarray([0x01, 0x02, 0x80, 0x81, 0x82], np.uint8)  # start, stop, pre-op, resets
FLAP = np.asarray([0x05, 0x7F, 0x04], np.uint8)  # operational, pre-operational, stopped
BAD_DLC = np.asarray([0, 1, 3, 4, 5, 6, 7, 8], np.uint8)  # every DLC an NMT command must not have


def _frames(i: np.ndarray, us: np.ndarray, can_id: np.ndarray, dlc: np.ndarray,
            data: np.ndarray) -> Frames:
    data = data.astype(np.uint8)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0
    return Frames(T0_US + us.astype(np.int64), can_id.astype(np.uint16), dlc.astype(np.uint8),
                  data)


def flapping(i: np.ndarray) -> Frames:
    """16 nodes, 20 ms heartbeats; a boot-up each, then every heartbeat a new state."""
    nodes = 16
    node = i % nodes + 1
    rnd = i // nodes
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = np.where(rnd == 0, 0x00, FLAP[(rnd - 1) % 3])
    return _frames(i, i * 20_000 // nodes, 0x700 + node, np.ones(len(i), np.uint8), data)


def commands(i: np.ndarray) -> Frames:
    """Every command specifier to every node-ID 0..127 in turn (1 ms apart); every fifth
    frame a heartbeat (05h) of one of 16 nodes."""
    hb = i % 5 == 4
    c = (i // 5) * 4 + i % 5  # index among the commands
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = np.where(hb, 0x05, COMMANDS[c % 5])
    data[:, 1] = np.where(hb, 0, (c // 5) % 128)
    can_id = np.where(hb, 0x700 + (i // 5) % 16 + 1, 0)
    dlc = np.where(hb, 1, 2)
    return _frames(i, i * 1000, can_id, dlc, data)


def findings(i: np.ndarray) -> Frames:
    """Malformed NMT commands 200 us apart, DLC cycling through 0, 1, 3, ..., 8."""
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = 0x01
    data[:, 1] = i % 127 + 1
    data[:, 2:] = (i % 251)[:, None]
    return _frames(i, i * 200, np.zeros(len(i), np.int64), BAD_DLC[i % len(BAD_DLC)], data)


def nodes127(i: np.ndarray) -> Frames:
    """Heartbeats (05h) of nodes 1..127, each every 100 ms, nothing else."""
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = 0x05
    return _frames(i, i * 100_000 // 127, 0x700 + i % 127 + 1, np.ones(len(i), np.uint8), data)


def emcy(i: np.ndarray) -> Frames:
    """EMCYs of 16 nodes 100 us apart (error code and register cycling); every fifth
    frame a heartbeat (05h) of one of them."""
    hb = i % 5 == 4
    node = (i // 5) % 16 + 1
    data = np.zeros((len(i), 8), np.uint8)
    code = np.asarray([0x0000, 0x1000, 0x2310, 0x3210, 0x8110, 0x8130], np.int64)[i % 6]
    data[:, 0] = np.where(hb, 0x05, code & 0xFF)
    data[:, 1] = np.where(hb, 0, code >> 8)
    data[:, 2] = np.where(hb, 0, np.where(code == 0, 0, 0x01 | (i & 0x10)))
    can_id = np.where(hb, 0x700, 0x080) + node
    return _frames(i, i * 100, can_id, np.where(hb, 1, 8), data)


def sdo(i: np.ndarray) -> Frames:
    """SDO expedited downloads of 1017h (50..305 ms) to 16 nodes, each confirmed by the
    next frame, 100 us apart; every fifth frame a heartbeat (05h) of one of them."""
    hb = i % 5 == 4
    k = (i // 5) * 4 + i % 5  # position among the SDO frames: request, response, ...
    node = (k // 2) % 16 + 1
    response = k % 2 == 1
    ms = 50 + (k // 32) % 256
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = np.where(hb, 0x05, np.where(response, 0x60, 0x2B))
    data[:, 1] = np.where(hb, 0, 0x17)
    data[:, 2] = np.where(hb, 0, 0x10)
    data[:, 4] = np.where(hb | response, 0, ms & 0xFF)
    data[:, 5] = np.where(hb | response, 0, ms >> 8)
    can_id = np.where(hb, 0x700 + (i // 5) % 16 + 1, np.where(response, 0x580, 0x600) + node)
    return _frames(i, i * 100, can_id, np.where(hb, 1, 8), data)


def aborts(i: np.ndarray) -> Frames:
    """SDO aborts of a download to 1017h from 16 servers 100 us apart; every fifth frame a
    heartbeat (05h) of one of them."""
    hb = i % 5 == 4
    node = (i // 5) % 16 + 1
    data = np.zeros((len(i), 8), np.uint8)
    data[:, :8] = np.asarray([0x80, 0x17, 0x10, 0x00, 0x11, 0x00, 0x09, 0x06], np.uint8)
    data[hb, :] = 0
    data[hb, 0] = 0x05
    can_id = np.where(hb, 0x700, 0x580) + node
    return _frames(i, i * 100, can_id, np.where(hb, 1, 8), data)


def boots(i: np.ndarray, refuse: bool = False) -> Frames:
    """A flood of CiA 302-2 boot processes (SPEC §8): 16 nodes in turn, each a boot-up, the
    manager's probe (upload 1000h) and its answer, an identity upload (1018h:01) and its
    answer, a configuration download (1017h) and its confirmation, and a direct start,
    100 us apart: a boot process per 8 frames."""
    k = i % 8
    node = (i // 8) % 16 + 1
    rows = np.asarray([
        [0x00, 0, 0, 0, 0, 0, 0, 0],  # boot-up
        [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0],  # probe
        [0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00],
        [0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0],  # vendor-ID
        [0x43, 0x18, 0x10, 0x01, 0x00, 0x03, 0x00, 0x00],
        [0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0],  # 1017h = 100 ms
        [0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0],
        [0x01, 0, 0, 0, 0, 0, 0, 0],  # start (node-ID below)
    ], np.uint8)
    if refuse:  # the node refuses the download: abort 06010002h (attempt to write read-only)
        rows[6] = [0x80, 0x17, 0x10, 0x00, 0x02, 0x00, 0x01, 0x06]
    data = rows[k].copy()
    data[k == 7, 1] = node[k == 7]
    base = np.asarray([0x700, 0x600, 0x580, 0x600, 0x580, 0x600, 0x580, 0x000])[k]
    can_id = base + np.where(k == 7, 0, node)
    dlc = np.where(k == 0, 1, np.where(k == 7, 2, 8))
    return _frames(i, i * 100, can_id, dlc, data)


def bootfail(i: np.ndarray) -> Frames:
    """`boots` with every 1017h download refused (abort 06010002h): no network file is
    needed, the probe and the 1018h:01 upload are the boot signature (SPEC_BOOT §8.2.4),
    and each process fails with one P003 (letter J, started anyway)."""
    return boots(i, refuse=True)


def guarded(i: np.ndarray) -> Frames:
    """Node guarding of 16 nodes, each every 100 ms: the master's remote request 700h+N,
    N's answer 2 ms later (05h, operational, its toggle bit alternating), nothing else."""
    pair, answer = i // 2, i % 2 == 1
    node = pair % 16 + 1
    rnd = pair // 16
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = np.where(answer, 0x05 | ((rnd % 2) << 7), 0)
    us = rnd * 100_000 + (node - 1) * 6_250 + np.where(answer, 2_000, 0)
    f = _frames(i, us, 0x700 + node, np.where(answer, 1, 0), data)
    f.rtr = ~answer
    return f


def keepalive(i: np.ndarray) -> Frames:
    """A master that repeats "start all nodes" (01h 00h) every 500 ms, as some keep their
    network operational, among the heartbeats (05h) of 16 nodes every 100 ms: one NMT
    command per 80 heartbeats, each node operational and obeying throughout."""
    per = 81  # 80 heartbeats, then the command, every 500 ms
    k, j = i // per, i % per
    command = j == per - 1
    node = j % 16 + 1
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = np.where(command, 0x01, 0x05)
    us = k * 500_000 + np.where(command, 499_000, (j // 16) * 100_000 + (node - 1) * 6_000)
    return _frames(i, us, np.where(command, 0, 0x700 + node), np.where(command, 2, 1), data)


def _beats(i: np.ndarray, us: np.ndarray, node: np.ndarray, order: np.ndarray) -> Frames:
    """Heartbeats (05h) of these nodes at these times, in `order`."""
    data = np.zeros((len(i), 8), np.uint8)
    data[:, 0] = 0x05
    return _frames(i, us[order], 0x700 + node[order], np.ones(len(i), np.uint8), data)


def jitter(i: np.ndarray) -> Frames:
    """8 nodes' heartbeats every 10 ms +-0.5 ms (uniform), in time order: the rounds do not
    overlap (node N at N ms), so a chunk of whole rounds sorts on its own."""
    rng = np.random.default_rng(int(i[0]))
    node = i % 8 + 1
    t = (i // 8) * 10_000 + node * 1_000 + rng.uniform(-500, 500, len(i))
    return _beats(i, np.round(t), node, np.argsort(t, kind="stable"))


def wander(i: np.ndarray) -> Frames:
    """`jitter`'s heartbeats written in bus order, each node's stamps off by up to 0.1 s
    (0.1 s x a sine of 60 + 7 N seconds): out of order by up to 0.2 s."""
    rng = np.random.default_rng(int(i[0]))
    node = i % 8 + 1
    true = (i // 8) * 10_000 + node * 1_000 + rng.uniform(-500, 500, len(i))
    stamp = true + 100_000 * np.sin(2 * np.pi * true / ((60 + 7 * node) * 1e6) + node)
    return _beats(i, np.round(stamp + 100_000), node, np.argsort(true, kind="stable"))


def restarts(i: np.ndarray) -> Frames:
    """A block of 4,000 heartbeats of 4 nodes every 1 ms, again and again: time goes back
    to the start every second (a logger that resets its clock)."""
    j = i % 4000
    node = j % 4 + 1
    return _beats(i, (j // 4) * 1_000 + node * 100, node, np.arange(len(i)))


MAKERS: dict[str, Callable[[np.ndarray], Frames]] = {
    "flapping": flapping, "commands": commands, "findings": findings, "nodes127": nodes127,
    "emcy": emcy, "sdo": sdo, "aborts": aborts, "boots": boots,
    "bootfail": bootfail, "guarded": guarded, "keepalive": keepalive, "jitter": jitter,
    "wander": wander, "restarts": restarts}


def chunks(kind: str, n: int) -> Iterator[Frames]:
    if kind == "clean":
        yield from traffic(n)
        return
    make = MAKERS[kind]
    for a in range(0, n, CHUNK_FRAMES):
        yield make(np.arange(a, min(n, a + CHUNK_FRAMES), dtype=np.int64))


def label(n: int) -> str:
    return f"{n // 10**6}M" if n % 10**6 == 0 else str(n)


def channels_lines(n: int) -> Iterator[bytes]:
    """N/2 interfaces of two frames each: 705#00 on every one, then 185#01 on every one."""
    half = max(n // 2, 1)
    for a in range(0, n, CHUNK_FRAMES):
        yield "".join(
            f"({1_700_000_000 + i / 1000:.6f}) c{i % half} {'705#00' if i < half else '185#01'}\n"
            for i in range(a, min(n, a + CHUNK_FRAMES))).encode()


def chanbeats_lines(n: int) -> Iterator[bytes]:
    """N/4 interfaces: a boot-up of node 5 on each, then three heartbeats, 100 ms apart."""
    q = max(n // 4, 1)
    for a in range(0, n, CHUNK_FRAMES):
        yield "".join(
            f"({1_700_000_000 + (i // q) / 10 + (i % q) / 1_000_000:.6f}) c{i % q} "
            f"705#{'00' if i < q else '05'}\n"
            for i in range(a, min(n, a + CHUNK_FRAMES))).encode()


def canids_lines(n: int) -> Iterator[bytes]:
    """Every 11-bit CAN-ID in turn, one data byte, 100 us apart."""
    for a in range(0, n, CHUNK_FRAMES):
        yield "".join(f"({1_700_000_000 + i / 10_000:.6f}) can0 {i % 2048:03X}#{i % 251:02X}\n"
                      for i in range(a, min(n, a + CHUNK_FRAMES))).encode()


def _wide_lines(n: int, ident: Callable[[int], str]) -> Iterator[bytes]:
    for a in range(0, n, CHUNK_FRAMES):
        yield "".join(
            f"({1_700_000_000 + i / 10_000:.6f}) can0 "
            + (f"{0x701 + (i // 5) % 16:03X}#05" if i % 5 == 4 else ident(i)) + "\n"
            for i in range(a, min(n, a + CHUNK_FRAMES))).encode()


TEXT_MAKERS: dict[str, Callable[[int], Iterator[bytes]]] = {
    "channels": channels_lines, "chanbeats": chanbeats_lines, "canids": canids_lines,
    "extended": lambda n: _wide_lines(n, lambda i: f"{0x18FEF100 + i % 256:08X}#"
                                                   f"{i % 4096:04X}00000000FFFF"),
    "errorframes": lambda n: _wide_lines(n, lambda i: "20000004#0000080000000000"),
}


def generate(kind: str, n: int, data: Path, zst: bool = False) -> Path:
    """The candump log (written unless already there); `zst`: compressed as it is made
    (`.log.zst`), so a log of 10 GiB needs a few MB of disk, not 10 GiB."""
    path = data / f"{kind}-{label(n)}.log{'.zst' if zst else ''}"
    if not path.exists():
        data.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        with tmp.open("wb") as raw:
            if zst:
                import zstandard

                out: Any = zstandard.ZstdCompressor(level=3).stream_writer(raw)
            else:
                out = raw
            if kind in TEXT_MAKERS:
                for piece in TEXT_MAKERS[kind](n):
                    out.write(piece)
            else:
                for f in chunks(kind, n):
                    out.write(candump_lines(f))
            if zst:
                out.flush(zstandard.FLUSH_FRAME)
        os.replace(tmp, path)
    return path


# Runs `argv` (from a JSON spec in argv[1]) in its own session under RLIMIT_AS, kills the
# group on timeout, samples the summed RSS of the process tree from /proc every 20 ms and
# prints one JSON line. It imports nothing big: a child's ru_maxrss starts at its parent's
# RSS at fork (see bench/run.py), and the tool must not inherit ours.
LAUNCHER = r"""
import json, os, resource, signal, subprocess, sys, threading, time
spec = json.loads(sys.argv[1])
page = os.sysconf("SC_PAGE_SIZE")

def kids(pid):
    try:
        out = []
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(x) for x in f.read().split()]
        return out
    except OSError:
        return []

def tree_rss(root):
    total, todo, seen = 0, [root], set()
    while todo:
        pid = todo.pop()
        if pid in seen:
            continue
        seen.add(pid)
        try:
            with open(f"/proc/{pid}/statm") as f:
                total += int(f.read().split()[1]) * page
        except (OSError, ValueError, IndexError):
            continue
        todo += kids(pid)
    return total, len(seen)

def limit():
    if spec["mem_bytes"]:
        resource.setrlimit(resource.RLIMIT_AS, (spec["mem_bytes"], spec["mem_bytes"]))

err = open(spec["stderr"], "wb")
t0 = time.perf_counter()
p = subprocess.Popen(spec["argv"], stdout=subprocess.DEVNULL, stderr=err, cwd=spec["cwd"],
                     start_new_session=True, preexec_fn=limit)
peak = [0, 0]
done = threading.Event()

def sample():
    while not done.is_set():
        rss, procs = tree_rss(p.pid)
        peak[0] = max(peak[0], rss)
        peak[1] = max(peak[1], procs)
        done.wait(0.02)

threading.Thread(target=sample, daemon=True).start()
timed_out = False
try:
    p.wait(spec["timeout"])
except subprocess.TimeoutExpired:
    timed_out = True
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
seconds = time.perf_counter() - t0
done.set()
try:
    os.killpg(p.pid, signal.SIGKILL)  # workers left behind
except OSError:
    pass
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"code": p.returncode, "seconds": seconds, "tree_peak": peak[0],
                  "procs": peak[1], "maxrss_kb": ru.ru_maxrss, "timed_out": timed_out}))
"""

OOM_MARKS = ("MemoryError", "Unable to allocate", "Cannot allocate memory", "std::bad_alloc")


@dataclass
class Row:
    n: int
    kind: str
    output: str
    status: str = "ok"  # ok, timeout, out of memory, failed (code), skipped (...)
    seconds: float | None = None
    tree_mb: float | None = None
    single_mb: float | None = None
    procs: int = 0
    code: int | None = None
    report_mb: float | None = None
    kept: int | None = None
    omitted: int | None = None
    by_rule: Counter[str] = field(default_factory=Counter)
    timeline: int | None = None
    events: int | None = None
    note: str = ""


def read_json_report(path: Path, row: Row) -> None:
    try:
        rep = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        row.note = f"report unreadable: {exc}"
        return
    row.kept = len(rep.get("findings", []))
    row.omitted = sum(int(o.get("count", 0)) for o in rep.get("omitted", []))
    row.by_rule = Counter(f.get("rule", "?") for f in rep.get("findings", []))
    for o in rep.get("omitted", []):
        row.by_rule[o.get("rule", "?")] += int(o.get("count", 0))
    row.timeline = len(rep.get("timeline", []))
    row.events = len(rep.get("events", []))


def run_one(nmtcheck: list[str], log: Path, kind: str, n: int, output: str, work: Path,
            timeout: float, mem_mb: int, extra: list[str]) -> Row:
    row = Row(n, kind, output)
    work.mkdir(parents=True, exist_ok=True)
    report = work / f"report-{kind}-{label(n)}.{output}"
    report.unlink(missing_ok=True)
    argv = [*nmtcheck, "check", str(log), "--format", "text", *extra]
    if output != "text":
        argv += ["-o", str(report)]
    stderr = work / f"stderr-{kind}-{label(n)}-{output}.txt"
    spec = {"argv": argv, "timeout": timeout, "mem_bytes": mem_mb * 2**20, "cwd": str(work),
            "stderr": str(stderr)}
    try:
        out = subprocess.run([sys.executable, "-c", LAUNCHER, json.dumps(spec)],
                             capture_output=True, text=True, timeout=timeout + 120, cwd=work)
        res = json.loads(out.stdout.strip().splitlines()[-1])
    except (subprocess.TimeoutExpired, ValueError, IndexError) as exc:
        row.status, row.note = "launcher failed", str(exc)[:200]
        return row
    row.seconds, row.code, row.procs = res["seconds"], res["code"], res["procs"]
    row.tree_mb, row.single_mb = res["tree_peak"] / 2**20, res["maxrss_kb"] / 1024
    err = stderr.read_text(errors="replace") if stderr.exists() else ""
    if res["timed_out"]:
        row.status = "timeout"
    elif any(m in err for m in OOM_MARKS) or (row.code == -9 and mem_mb):
        row.status = "out of memory"
    elif row.code not in (0, 1):
        row.status = f"failed ({row.code})"
        row.note = err.strip().splitlines()[-1][:200] if err.strip() else ""
    if report.exists():
        row.report_mb = report.stat().st_size / 2**20
        if output == "json" and row.status == "ok":
            read_json_report(report, row)
        report.unlink()  # reports of pathological logs are big
    return row


def fmt(x: float | None, spec: str = ".2f") -> str:
    return "" if x is None else format(x, spec)


def render(rows: list[Row]) -> str:
    clean = {(r.n, r.output): r for r in rows if r.kind == "clean" and r.status == "ok"}
    json_of = {(r.n, r.kind): r for r in rows if r.output == "json" and r.kept is not None}
    lines = ["| frames | log | output | time (s) | peak RSS tree (MB) | max RSS 1 proc (MB) "
             "| procs | exit | findings kept / omitted | report (MB) | time ÷ clean "
             "| RSS ÷ clean |",
             "|---:|---|---|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    for r in rows:
        size = f"{r.n / 1e6:g} M"
        if r.status.startswith("skipped") or r.seconds is None:
            lines.append(f"| {size} | {r.kind} | {r.output} | {r.status} | | | | | | | | |")
            continue
        exit_ = str(r.code) if r.status == "ok" else f"{r.code}: **{r.status}**"
        j = json_of.get((r.n, r.kind))
        counts = (f"{j.kept:,} / {j.omitted:,}" if j is not None else "")
        c = clean.get((r.n, r.output))
        ratio_t = ratio_m = ""
        if c is not None and r.kind != "clean" and r.status == "ok":
            assert r.seconds is not None and c.seconds is not None  # both ran: "ok"
            ratio_t = f"{r.seconds / c.seconds:.1f}×"
            ratio_m = f"{(r.tree_mb or 0) / (c.tree_mb or 1):.1f}×"
        time_s = fmt(r.seconds) if r.status == "ok" else f"≥ {r.seconds:.0f}"
        lines.append(f"| {size} | {r.kind} | {r.output} | {time_s} | {fmt(r.tree_mb, '.0f')} | "
                     f"{fmt(r.single_mb, '.0f')} | {r.procs} | {exit_} | {counts} | "
                     f"{fmt(r.report_mb, '.1f')} | {ratio_t} | {ratio_m} |")
    out = "\n".join(lines) + "\n"
    yields = [r for r in rows if r.output == "json" and r.kept is not None]
    if yields:
        out += ("\nWhat each log yields (from its JSON report; findings per rule count the "
                "omitted ones too):\n\n| frames | log | timeline entries | events "
                "| findings by rule |\n|---:|---|---:|---:|---|\n")
        for r in yields:
            rules = ", ".join(f"{k} {v:,}" for k, v in sorted(r.by_rule.items()))
            out += (f"| {r.n / 1e6:g} M | {r.kind} | {r.timeline:,} | {r.events:,} | "
                    f"{rules or 'none'} |\n")
    return out


def nmtcheck_version(nmtcheck: list[str]) -> str:
    try:
        out = subprocess.run([*nmtcheck, "--version"], capture_output=True, text=True,
                             timeout=60)
        return out.stdout.strip() or out.stderr.strip()
    except (OSError, subprocess.TimeoutExpired):
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1M")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--outputs", default=",".join(OUTPUTS),
                    help="text (stdout only) and/or report suffixes written with -o")
    ap.add_argument("--nmtcheck", default="nmtcheck",
                    help="the command to run (split like a shell does)")
    ap.add_argument("--extra", default="", help="more options for `nmtcheck check`")
    ap.add_argument("--data", type=Path, default=Path("/tmp/nmtcheck-patho"))
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per run")
    ap.add_argument("--mem-mb", type=int, default=4096,
                    help="address-space limit per process (RLIMIT_AS), 0: none")
    ap.add_argument("--big-if-1m-under", type=float, default=60.0,
                    help="run sizes above 1 M only for kinds/outputs whose 1 M run took less")
    ap.add_argument("--write", action="store_true", help="write bench/PATHOLOGICAL.md")
    ap.add_argument("--append", action="store_true", help="add a section instead")
    ap.add_argument("--label", default="", help="the section's title, e.g. Before")
    ap.add_argument("--results", type=Path, default=HERE / "PATHOLOGICAL.md")
    ap.add_argument("--generate-only", action="store_true")
    ap.add_argument("--zst", action="store_true",
                    help="write the logs zstd-compressed (.log.zst; a 10 GiB log in MB)")
    args = ap.parse_args()
    sizes = sorted(parse_size(s) for s in args.sizes.split(","))
    kinds = args.kinds.split(",")
    outputs = args.outputs.split(",")
    for k in kinds:
        if k not in KINDS:
            ap.error(f"unknown kind {k} (one of {', '.join(KINDS)})")
    nmtcheck = shlex.split(args.nmtcheck)
    extra = shlex.split(args.extra)
    rows: list[Row] = []
    first: dict[tuple[str, str], Row] = {}
    for n in sizes:
        for kind in kinds:
            print(f"generating {n:,} frames of {kind} …", file=sys.stderr, flush=True)
            log = generate(kind, n, args.data, args.zst)
            if args.generate_only:
                continue
            for output in outputs:
                small = first.get((kind, output))
                if n > 10**6 and small is not None and (
                        small.status != "ok" or (small.seconds or 0) > args.big_if_1m_under):
                    why = small.status if small.status != "ok" else f"{small.seconds:.0f} s"
                    rows.append(Row(n, kind, output, f"skipped (1 M: {why})"))
                    continue
                r = run_one(nmtcheck, log, kind, n, output, args.data / "work", args.timeout,
                            args.mem_mb, extra)
                first.setdefault((kind, output), r)
                rows.append(r)
                print(f"  {label(n)} {kind} {output}: {r.status} {fmt(r.seconds)} s "
                      f"tree {fmt(r.tree_mb, '.0f')} MB, 1 proc {fmt(r.single_mb, '.0f')} MB "
                      f"{r.note}", file=sys.stderr, flush=True)
    if args.generate_only:
        return
    cmd = "python bench/pathological.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    header = (f"Measured {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC on {machine()}; "
              f"{nmtcheck_version(nmtcheck)} (`{args.nmtcheck}`).\n"
              f"Command: `{cmd}`.\n\n"
              f"Each run is `nmtcheck check LOG --format text{' ' + args.extra if extra else ''}"
              f"` (stdout to /dev/null) plus `-o report.OUTPUT` unless OUTPUT is text, once, "
              f"under a {args.mem_mb} MB address-space limit and a {args.timeout:g} s timeout. "
              "*Peak RSS tree*: the largest sum of RSS over the tool's process tree, sampled "
              "from /proc every 20 ms (shared pages count once per process); *max RSS 1 proc*: "
              "the largest ru_maxrss of any one process (RUSAGE_CHILDREN); *procs*: the most "
              "processes seen at once. Findings come from the JSON run of the same log. "
              "Ratios are to the clean log of the same size and output.\n\n")
    text = header + render(rows)
    print(text)
    if args.write:
        title = f"## {args.label}\n\n" if args.label else ""
        if args.append and args.results.exists():
            args.results.write_text(args.results.read_text().rstrip() + "\n\n" + title + text)
        else:
            args.results.write_text(
                "# Pathological logs\n\nGoal: any 5 M-frame log, however many "
                "events, state changes, commands or findings it holds, in seconds and under "
                "500 MB (peak RSS of the whole process tree). Regenerate with the command "
                "below; `--append --label After` adds a section.\n\n" + title + text)


if __name__ == "__main__":
    main()

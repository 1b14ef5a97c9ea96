"""The speed benchmark: nmtcheck against python-can and canopen-lens on the same logs.

    python bench/run.py                      # 1M/5M/20M frames, every format, 3 rounds
    python bench/run.py --sizes 1M --rounds 1 --formats candump

Generates realistic CANopen traffic (bench/traffic.py) as candump, ASC, BLF and
MCAP under --data (default /tmp/nmtcheck-bench, kept between runs), installs
canopen-lens from PyPI into its own venv there, then times whole processes,
alternating the tools within each round: `nmtcheck check LOG --format json`,
python-can's LogReader merely iterating, python-can plus a naive per-frame NMT
tracker (bench/peers.py), and canopen-lens on candump. Each cell is the median
wall time over the rounds; peak RSS is the child's own (wait4). The table is
printed and written to bench/RESULTS.md with the date and the machine.

Regressions: the medians are also compared with the stored figures of the previous
run on the same machine (bench/figures.json: per machine, the last run's seconds per
size, format and tool, with the commit they came from). The "÷ previous" column is
this run's time over the stored one; an nmtcheck row 10 % or more slower is listed
as a regression at the end, unless python-can on the same log slowed down as much (the
machine was busier). `--save` stores this run's figures as the new previous
ones; `--checkout DIR` times another checkout's nmtcheck (e.g. a worktree of the
previous release, to store its figures):

    python bench/run.py --sizes 2M --formats blf --checkout /tmp/base --save
    python bench/run.py --sizes 2M --formats blf      # now against those figures
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
from bytecode import ensure_bytecode  # noqa: E402
from generate import FORMATS, generate  # noqa: E402

LENS_VERSION = "0.5.1"
FIGURES = HERE / "figures.json"
REGRESSION = 1.10  # an nmtcheck time this much over the stored one is reported
PYTHON_CAN_FORMATS = {"candump", "asc", "blf"}  # python-can has no MCAP reader


@dataclass
class Tool:
    name: str
    formats: set[str]
    command: list[str]  # LOG is substituted
    env: dict[str, str] = field(default_factory=dict)

    def argv(self, log: Path) -> list[str]:
        return [str(log) if a == "LOG" else a for a in self.command]


@dataclass
class Sample:
    seconds: float
    peak_rss_mb: float
    ok: bool


# A child's peak RSS starts at its parent's RSS at fork (Linux keeps the high-water mark
# across exec), and this process holds generated data: each run goes through a small
# launcher that times the tool and reports the tool's own peak.
LAUNCHER = ("import os, subprocess, sys, time; t = time.perf_counter(); "
            "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, "
            "stderr=subprocess.PIPE); err = p.stderr.read(); _, st, ru = os.wait4(p.pid, 0); "
            "print(os.waitstatus_to_exitcode(st), ru.ru_maxrss, time.perf_counter() - t); "
            "sys.stderr.write(err.decode(errors='replace')[-300:])")


def run_once(tool: Tool, log: Path) -> Sample:
    """Wall time and peak RSS of one run of the tool."""
    out = subprocess.run([sys.executable, "-c", LAUNCHER, *tool.argv(log)],
                         env=dict(os.environ, **tool.env), capture_output=True, text=True)
    code, kb, seconds = out.stdout.split()
    ok = int(code) in (0, 1)  # 1: findings (nmtcheck) or problems (canopen-lens --check)
    if not ok:
        print(f"  {tool.name} failed ({code}): {out.stderr.strip()}", file=sys.stderr)
    return Sample(float(seconds), int(kb) / 1024, ok)


def lens_venv(data: Path) -> Path | None:
    """canopen-lens in the benchmark's own venv (never in the project's environment)."""
    venv = data / "lens-venv"
    exe = venv / "bin" / "canopen-lens"
    if exe.exists():
        return exe
    try:
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(venv / "bin" / "pip"), "install", "-q",
                        f"canopen-lens=={LENS_VERSION}"], check=True)
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"canopen-lens not available: {exc}", file=sys.stderr)
        return None
    return exe


def nmtcheck_formats(checkout: Path = REPO) -> set[str]:
    """The formats the checkout reads (others report n/a)."""
    out = subprocess.run([sys.executable, "-P", "-c", "from nmtcheck.readers import "
                          "FORMAT_MODULES; print(' '.join(FORMAT_MODULES))"],
                         env=dict(os.environ, PYTHONPATH=str(checkout)), check=True,
                         capture_output=True, text=True)
    return set(out.stdout.split())


def tools(data: Path, with_lens: bool, checkout: Path = REPO) -> list[Tool]:
    py = sys.executable
    out = [  # -P: the checkout's nmtcheck, never the working directory's
        Tool("nmtcheck", nmtcheck_formats(checkout) & set(FORMATS),
             [py, "-P", "-m", "nmtcheck", "check", "LOG", "--format", "json", "--fail-on",
              "never"], {"PYTHONPATH": str(checkout)}),
        Tool("python-can iterate", PYTHON_CAN_FORMATS,
             [py, str(HERE / "peers.py"), "iterate", "LOG"]),
        Tool("python-can + naive tracker", PYTHON_CAN_FORMATS,
             [py, str(HERE / "peers.py"), "track", "LOG"]),
    ]
    exe = lens_venv(data) if with_lens else None
    if exe is not None:
        out.append(Tool(f"canopen-lens {LENS_VERSION}", {"candump"},
                        [str(exe), "LOG", "--check", "--no-color"]))
    return out


def parse_size(text: str) -> int:
    text = text.strip().upper()
    return int(float(text[:-1]) * 10**6) if text.endswith("M") else int(text)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 2**20:.0f} GB RAM"
    except (OSError, ValueError, IndexError):
        pass
    import numpy

    return (f"{cpu}, {os.cpu_count()} cores{mem}; Python "
            f"{platform.python_version()}, numpy {numpy.__version__}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1M,5M,20M")
    ap.add_argument("--formats", default=",".join(FORMATS))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--peers-up-to", default="20M",
                    help="skip the (slow) peers above this many frames")
    ap.add_argument("--data", type=Path, default=Path("/tmp/nmtcheck-bench"))
    ap.add_argument("--no-lens", action="store_true")
    ap.add_argument("--results", type=Path, default=HERE / "RESULTS.md")
    ap.add_argument("--checkout", type=Path, default=REPO,
                    help="the checkout whose nmtcheck is timed (default: this one)")
    ap.add_argument("--figures", type=Path, default=FIGURES,
                    help="stored figures of the previous run, per machine")
    ap.add_argument("--save", action="store_true",
                    help="store this run's figures in --figures as the previous ones")
    args = ap.parse_args()
    previous = load_figures(args.figures).get(machine())
    sizes = [parse_size(s) for s in args.sizes.split(",")]
    formats = args.formats.split(",")
    peers_limit = parse_size(args.peers_up_to)
    all_tools = tools(args.data, not args.no_lens, args.checkout)
    print(ensure_bytecode(args.checkout), file=sys.stderr)
    rows: list[tuple[int, str, str, Sample | None, float | None]] = []
    for n in sizes:
        for fmt in formats:
            print(f"generating {n:,} frames as {fmt} …", file=sys.stderr, flush=True)
            log = generate(n, args.data, fmt)
            todo = [t for t in all_tools if fmt in t.formats
                    and (t.name == "nmtcheck" or n <= peers_limit)]
            samples: dict[str, list[Sample]] = {t.name: [] for t in todo}
            for r in range(args.rounds):
                for t in todo:  # alternating: every tool once per round
                    s = run_once(t, log)
                    samples[t.name].append(s)
                    print(f"  round {r + 1} {fmt} {n:,} {t.name}: {s.seconds:.2f} s "
                          f"{s.peak_rss_mb:.0f} MB", file=sys.stderr, flush=True)
            for t in all_tools:
                got = samples.get(t.name)
                if got is None and t.name != "nmtcheck" and fmt in t.formats:
                    continue  # a peer not run at this size (--peers-up-to)
                if not got or not all(s.ok for s in got):
                    rows.append((n, fmt, t.name, None, None))  # no reader for the format
                    continue
                med = Sample(statistics.median(s.seconds for s in got),
                             max(s.peak_rss_mb for s in got), True)
                rows.append((n, fmt, t.name, med, n / med.seconds))
    before = previous["seconds"] if previous else {}
    table = (render(rows, args.rounds, before) + regressions(rows, before)
             + jobs_table(args.data, formats, args.rounds, args.checkout))
    commit = describe(args.checkout)
    against = (f"÷ previous: against the figures of {previous['date']} ({previous['commit']}) "
               f"stored in {args.figures.name} for this machine" if previous else
               f"÷ previous: no stored figures for this machine in {args.figures.name}")
    header = (f"Measured {dt.date.today().isoformat()} on {machine()}, nmtcheck at {commit}.\n"
              f"Command: `python bench/run.py --sizes {args.sizes} --formats {args.formats} "
              f"--rounds {args.rounds} --peers-up-to {args.peers_up_to}`; medians of "
              f"{args.rounds} alternating rounds, whole processes; peak RSS is the largest of "
              f"the rounds; n/a: no reader for that format; {against}.\n\n")
    print(header + table)
    args.results.write_text("# Benchmark results\n\n" + header + table)
    if args.save:
        save_figures(args.figures, rows, commit)


def row_key(n: int, fmt: str, tool: str) -> str:
    return f"{n / 1e6:g} M {fmt} {tool}"


def load_figures(path: Path) -> dict[str, dict[str, Any]]:
    """Stored figures by machine: {machine: {date, commit, seconds: {row key: s}}}."""
    try:
        stored: dict[str, dict[str, Any]] = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    return stored


def save_figures(path: Path, rows: list[tuple[int, str, str, Sample | None, float | None]],
                 commit: str) -> None:
    """This run's medians become the machine's previous figures (other rows are kept)."""
    stored = load_figures(path)
    mine = stored.setdefault(machine(), {"seconds": {}})
    mine.update(date=dt.date.today().isoformat(), commit=commit)
    for n, fmt, name, s, _rate in rows:
        if s is not None:
            mine["seconds"][row_key(n, fmt, name)] = round(s.seconds, 3)
    path.write_text(json.dumps(stored, indent=1, sort_keys=True) + "\n")
    print(f"figures stored in {path}", file=sys.stderr)


def describe(checkout: Path) -> str:
    """The checkout's commit (with -dirty for local changes), or 'unknown'."""
    try:
        out = subprocess.run(["git", "-C", str(checkout), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return out.stdout.strip()


def regressions(rows: list[tuple[int, str, str, Sample | None, float | None]],
                before: dict[str, float]) -> str:
    """The nmtcheck rows at least REGRESSION times slower than the stored figures, unless
    python-can on the same log slowed down as much (a busier machine, not nmtcheck)."""
    now = {(n, fmt, name): s.seconds for n, fmt, name, s, _r in rows if s is not None}
    slow = []
    for (n, fmt, name), seconds in now.items():
        old = before.get(row_key(n, fmt, name))
        if name != "nmtcheck" or not old or seconds < REGRESSION * old:
            continue
        peer_now = now.get((n, fmt, "python-can iterate"))
        peer_old = before.get(row_key(n, fmt, "python-can iterate"))
        machine_factor = peer_now / peer_old if peer_now and peer_old else 1.0
        if seconds / old / machine_factor < REGRESSION:
            continue
        slow.append(f"{n / 1e6:g} M {fmt} {old:.2f} s -> {seconds:.2f} s "
                    f"({seconds / old:.2f}×; python-can {machine_factor:.2f}×)")
    if not slow:
        return ""
    print("REGRESSION against the stored figures: " + "; ".join(slow), file=sys.stderr)
    return "\n**Slower than the stored figures:** " + "; ".join(slow) + ".\n"


def jobs_table(data: Path, formats: list[str], rounds: int, checkout: Path = REPO) -> str:
    """`-j 1` against `-j 2` on one 1 M-frame log per format, checked in one command."""
    readable = nmtcheck_formats(checkout)
    logs = [generate(10**6, data, fmt) for fmt in formats if fmt in readable]
    if len(logs) < 2:
        return ""
    py = sys.executable
    runs = {j: Tool(f"-j {j}", set(), [py, "-P", "-m", "nmtcheck", "check", "-j", str(j),
                                       *map(str, logs), "--format", "json", "--fail-on",
                                       "never"], {"PYTHONPATH": str(checkout)})
            for j in (1, 2)}
    times: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(rounds):
        for j, tool in runs.items():
            times[j].append(run_once(tool, Path()).seconds)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    return (f"\n{len(logs)} logs of 1 M frames ({', '.join(p.suffix[1:] for p in logs)}) in "
            f"one command: `-j 1` {one:.2f} s, `-j 2` {two:.2f} s ({one / two:.2f}×).\n")


def render(rows: list[tuple[int, str, str, Sample | None, float | None]], rounds: int,
           before: dict[str, float] | None = None) -> str:
    """Markdown: one line per (size, format, tool), with nmtcheck's speed-up over each peer
    and the time over the stored previous figures (÷ previous, > 1: slower)."""
    before = before or {}
    ours = {(n, fmt): rate for n, fmt, name, _s, rate in rows if name == "nmtcheck"}
    lines = ["| frames | format | tool | time (s) | frames/s | nmtcheck ÷ tool | peak RSS (MB) "
             "| ÷ previous |",
             "|---:|---|---|---:|---:|---:|---:|---:|"]
    for n, fmt, name, s, rate in rows:
        if s is None or rate is None:
            if name == "nmtcheck" or name.startswith("python-can"):
                lines.append(f"| {n / 1e6:g} M | {fmt} | {name} | n/a | n/a | | | |")
            continue
        mine = ours.get((n, fmt))
        ratio = "" if name == "nmtcheck" or not mine else f"{mine / rate:.2f}×"
        old = before.get(row_key(n, fmt, name))
        vs = f"{s.seconds / old:.2f}× (was {old:.2f})" if old else ""
        lines.append(f"| {n / 1e6:g} M | {fmt} | {name} | {s.seconds:.2f} | "
                     f"{rate / 1e6:.2f} M | {ratio} | {s.peak_rss_mb:.0f} | {vs} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()

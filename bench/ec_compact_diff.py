"""Compacted against whole, at scale and with the production settings (issue 24).

    python bench/ec_compact_diff.py                       # 3 M heartbeats of 16 nodes
    python bench/ec_compact_diff.py --frames 10M --network

Writes a candump log of 16 nodes' heartbeats (100 ms, ±2 ms jitter, 5 h at 3 M frames)
with two lost stretches (H001), a stop and a pre-operational command obeyed by node 7,
and with `--network` a network file configuring 1017h = 100 ms for every node while node
9 beats every 115 ms (H003, so node 9 must be read back whole). Checks it twice in this
process, with `ec_compact.SETTINGS` as shipped and with compaction off, and compares the
JSON and text reports: they must be identical. Prints time, kept and dropped rows.
`tests/test_ec_compact.py` does the same on small logs with forced settings.

With `--log PATH`, checks that log instead of writing one (a cut of a pathological log:
`head -n 1000000 jitter-20M.log > cut.log`; any format nmtcheck reads).

With `--keepalive`, a master sends "start all" every 500 ms throughout (node 7's stop and
pre-operational then last until the next one): runs of heartbeats pass the repeats.

With `--guarding`, nodes 9-16 answer node guarding instead (a remote request every
100 ms, the answer 2 ms later, its toggle bit alternating): node 11 misses one answer
(G002), node 13 repeats a toggle bit once (G001); with `--network` as well, nodes 9-16
get guard time 100 ms and life time factor 3 while node 15 is guarded every 350 ms
(G003 on every request, so node 15 must be read back whole).
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from run import parse_size  # noqa: E402

from nmtcheck.engine import check_input, select_rules  # noqa: E402
from nmtcheck.reporters import renderer  # noqa: E402
from nmtcheck.settings.network import load_network  # noqa: E402
from nmtcheck.settings.profiles import load_profile  # noqa: E402
from nmtcheck.timeline import ec_compact  # noqa: E402

DATE = re.compile(r"\d{4}-\d\d-\d\dT[0-9:.]+(Z|[+-]\d\d:\d\d)?")
OPTIONS: dict[str, object] = {"fail_on": "error", "quiet": False,
                              "config": {"file": None, "profile": "default", "overrides": []}}


def guarded(n: int, per: int, period: float, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`per` frames of node guarding of node n: request (data -1: `R`), answer."""
    pairs = per // 2
    t = 0.05 * n / 16 + np.arange(pairs) * period + rng.uniform(-0.002, 0.002, pairs)
    answer = 0x05 | (np.arange(pairs) % 2) << 7
    if n == 13:
        answer[pairs // 3] ^= 0x80  # the toggle bit repeats: G001
    ts = np.stack([t, t + 0.002], 1).ravel()
    data = np.stack([np.full(pairs, -1), answer], 1).ravel()
    keep = np.ones(len(ts), bool)
    if n == 11:
        keep[pairs + 1] = False  # one answer lost: G002
    return ts[keep], np.full(int(keep.sum()), 0x700 + n), data[keep]


def write_log(path: Path, frames: int, slow9: bool, guarding: bool = False,
              keepalive: bool = False) -> None:
    rng = np.random.default_rng(1)
    per = frames // 16
    parts = []
    for n in range(1, 17):
        if guarding and n >= 9:
            parts.append(guarded(n, per, 0.35 if slow9 and n == 15 else 0.1, rng))
            continue
        period = 0.115 if slow9 and n == 9 and not guarding else 0.1
        t = 0.05 * n / 16 + np.arange(per) * period + rng.uniform(-0.002, 0.002, per)
        keep = np.ones(per, bool)
        if n == 3:
            keep[per // 4:per // 4 + 4] = False  # 0.5 s lost: H001
        if n == 5:
            keep[per // 2:per // 2 + 100] = False  # 10 s lost: H001
        t = t[keep]
        state = np.full(len(t), 0x05)
        if n == 7 and keepalive:  # the next "start all" ends the stop and the pre-op
            state[(t > 3000.0) & (t <= 3000.5)] = 0x04
            state[(t > 9000.0) & (t <= 9000.5)] = 0x7F
        elif n == 7:  # stopped, then pre-operational, by the commands below
            state[t > 3000.0] = 0x04
            state[t > 9000.0] = 0x7F
        parts.append((t, np.full(len(t), 0x700 + n), state))
    commands = np.asarray([3000.0, 9000.0])
    command_data = np.asarray(["0207", "8007"])
    if keepalive:  # the master repeats "start all" every 500 ms
        every = np.arange(0.5, max(float(p[0].max()) for p in parts), 0.5)
        commands = np.concatenate([commands, every])
        command_data = np.concatenate([command_data, np.full(len(every), "0100")])
    ts = np.concatenate([p[0] for p in parts] + [commands])
    cid = np.concatenate([p[1] for p in parts] + [np.zeros(len(commands), np.int64)])
    values = np.concatenate([p[2] for p in parts])
    data = np.concatenate([np.where(values < 0, "R", np.char.mod("%02X", values & 0xFF)),
                           command_data])
    order = np.argsort(ts, kind="stable")
    with path.open("w") as f:
        for a, c, d in zip(ts[order].tolist(), cid[order].tolist(), data[order].tolist(),
                           strict=True):
            f.write(f"({1_700_000_000 + a:.6f}) can0 {c:03X}#{d}\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="3M")
    ap.add_argument("--network", action="store_true",
                    help="configure 1017h = 100 ms for all; node 9 beats every 115 ms")
    ap.add_argument("--guarding", action="store_true",
                    help="nodes 9-16 answer node guarding instead of producing heartbeats")
    ap.add_argument("--keepalive", action="store_true",
                    help="a master sends \"start all\" every 500 ms (node 7's stop and "
                         "pre-operational last until the next one)")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/nmtcheck-ecdiff"))
    ap.add_argument("--log", type=Path, help="check this log instead of a generated one")
    args = ap.parse_args()
    frames = parse_size(args.frames)
    args.dir.mkdir(parents=True, exist_ok=True)
    log = args.log or args.dir / (f"{'guard' if args.guarding else 'hb'}16-{frames}"
                                  f"{'-slow9' if args.network else ''}"
                                  f"{'-keepalive' if args.keepalive else ''}.log")
    if not log.exists():
        write_log(log, frames, args.network, args.guarding, args.keepalive)
    net = None
    if args.network:
        toml = args.dir / "network.toml"
        toml.write_text("".join(
            f"[nodes.{n}]\nguard_time_ms = 100\nlife_time_factor = 3\n\n"
            if args.guarding and n >= 9 else f"[nodes.{n}]\nheartbeat_ms = 100\n\n"
            for n in range(1, 17)))
        net = load_network(str(toml))
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    reports = {}
    for name, settings in (("whole", ec_compact.Compaction(above=1 << 62)),
                           ("compacted", ec_compact.Compaction())):
        ec_compact.SETTINGS = settings
        t0 = time.perf_counter()
        res = check_input(str(log), 0, profile, rules, network=net)
        decoded = res.model.decoded
        dropped = (sum(r.dropped for r in decoded.ec_runs.values())
                   + sum(g.dropped for g in decoded.ec_guard_runs.values()))
        print(f"{name}: {time.perf_counter() - t0:.1f} s, kept rows "
              f"{len(res.model.decoded.ec['ts']):,}, dropped {dropped:,}, "
              f"findings {len(res.findings)} ({', '.join(sorted({f.rule for f in res.findings}))})")
        reports[name] = {fmt: DATE.sub("<DATE>", renderer(fmt)([res], OPTIONS))
                         for fmt in ("json", "text")}
    same = reports["whole"] == reports["compacted"]
    print("reports identical:", same)
    if not same:
        for line in list(difflib.unified_diff(reports["whole"]["text"].splitlines(),
                                              reports["compacted"]["text"].splitlines(),
                                              lineterm=""))[:40]:
            print(line)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

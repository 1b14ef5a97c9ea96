"""Fleet throughput on many small logs: `--executor local` vs `dask-local` (with nmtcheck's
worker settings, and with Dask's defaults), writing a results dataset each time.

    python bench/fleet.py --files 400 --workers 2
    python bench/generate.py 2000000 /tmp/nmtcheck-bench --formats candump
    python bench/fleet.py --large /tmp/nmtcheck-bench/bench-2M.log   # Dask's worker defaults

Each log is a real sample (samples/*.log) laid out as DEVICE/SESSION/SPLIT.log for 20
devices, its timestamps moved by a day per session, so that the dataset is partitioned over
many dates as a fleet's is. Prints logs/s and MB/s
per executor, and the ratio to the local pool.

Scaling over the cores (local:1 ... local:N against `check -j N`, `xargs -PN`, the
machine's ceiling and dask-local:N, with the driver's CPU and bytes per log) is
bench/fleet_scaling.py.
"""

from __future__ import annotations

import argparse
import platform
import shutil
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from nmtcheck.fleet.storage import FileInfo

REPO = Path(__file__).resolve().parent.parent


def make_logs(root: Path, n: int) -> int:
    """n candump logs under DEVICE/SESSION/SPLIT.log; returns their total size."""
    samples = sorted((REPO / "samples").glob("*.log"))
    texts = [p.read_text().splitlines() for p in samples]
    total = 0
    for i in range(n):
        lines = texts[i % len(texts)]
        shift = 86400.0 * (i // 20)  # one session a day per device
        out = []
        for line in lines:
            if line.startswith("("):
                ts, rest = line[1:].split(")", 1)
                out.append(f"({float(ts) + shift:.6f}){rest}")
            else:
                out.append(line)
        dest = root / f"DEV{i % 20:02d}" / f"{i // 20:08d}" / "00000001.log"
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_text("\n".join(out) + "\n")
        total += dest.stat().st_size
    return total


def run(executor: str, logs: Path, results: Path, dask_defaults: bool = False) -> float:
    from nmtcheck.engine import select_rules
    from nmtcheck.fleet import executors
    from nmtcheck.fleet.run import FleetOptions, run_fleet
    from nmtcheck.settings.profiles import load_profile

    saved = dict(executors.DASK_CONFIG)
    if dask_defaults:
        executors.DASK_CONFIG.clear()
    try:
        profile = load_profile("default")
        codes = [r.code for r in select_rules(profile, [], [])]
        shutil.rmtree(results, ignore_errors=True)
        started = time.perf_counter()
        out = run_fleet(FleetOptions([str(logs / "**" / "*.log")], str(results),
                                     executor=executor), profile, codes, None)
        seconds = time.perf_counter() - started
        assert out.status["ok"] == out.files, out.status
        return seconds
    finally:
        executors.DASK_CONFIG.clear()
        executors.DASK_CONFIG.update(saved)


def timed_batch(files: list[FileInfo], cfg: object) -> tuple[float, float]:
    """Run in a worker: one task's wall and CPU seconds."""
    from nmtcheck.fleet.tasks import check_batch

    wall, cpu = time.perf_counter(), time.process_time()
    check_batch(files, cfg)  # type: ignore[arg-type]
    return time.perf_counter() - wall, time.process_time() - cpu


def per_task(log: Path, repeat: int) -> None:
    """One large log as one task on a worker of each executor: what Dask's worker defaults
    cost inside the task (wall and CPU seconds, best of `repeat`)."""
    from nmtcheck import __version__
    from nmtcheck.engine import select_rules
    from nmtcheck.fleet import executors
    from nmtcheck.fleet.dataset import Dataset
    from nmtcheck.fleet.storage import expand
    from nmtcheck.fleet.tasks import TaskConfig
    from nmtcheck.settings.profiles import load_profile

    profile = load_profile("default")
    codes = [r.code for r in select_rules(profile, [], [])]
    files = list(expand([str(log)], None, {}))
    with tempfile.TemporaryDirectory(prefix="nmtcheck-bench-task-") as tmp:
        cfg = TaskConfig(tmp, {}, profile, codes, None, None, False, None, {}, 10000, None,
                         __version__, "bench", "bench")
        Dataset(tmp).ensure()
        print(f"one task on {log.name} ({log.stat().st_size / 1e6:.0f} MB), best of {repeat}:")
        base = None
        for label, spec, defaults in [("local:1", "local:1", False),
                                      ("dask-local:1", "dask-local:1", False),
                                      ("dask-local:1, Dask's worker defaults", "dask-local:1",
                                       True)]:
            saved = dict(executors.DASK_CONFIG)
            if defaults:
                executors.DASK_CONFIG.clear()
            try:
                ex = executors.make_executor(spec)
            finally:
                executors.DASK_CONFIG.update(saved)
            times = []
            for i in range(repeat):
                ex.submit(i, timed_batch, files, cfg)
                while ex.pending():
                    times += [v for _k, v in ex.done()]
            ex.close()
            wall, cpu = min(times)
            base = base or wall
            print(f"  {label:<38} wall {wall:6.2f} s  cpu {cpu:6.2f} s  x{wall / base:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=400)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2, help="best of this many runs")
    ap.add_argument("--large", type=Path, default=None, metavar="LOG",
                    help="also time one task on this large log in each executor's worker "
                         "(e.g. bench-2M.log from bench/generate.py)")
    args = ap.parse_args()
    if args.large is not None:
        per_task(args.large, max(args.repeat, 3))
    with tempfile.TemporaryDirectory(prefix="nmtcheck-bench-fleet-") as tmp:
        logs = Path(tmp) / "logs"
        size = make_logs(logs, args.files)
        print(f"{args.files} logs, {size / 1e6:.1f} MB, {args.workers} workers, "
              f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
              f"{time.strftime('%Y-%m-%d')}")
        variants = [("local", f"local:{args.workers}", False),
                    ("dask-local", f"dask-local:{args.workers}", False),
                    ("dask-local, Dask's worker defaults", f"dask-local:{args.workers}", True)]
        base = None
        for label, spec, defaults in variants:
            best = min(run(spec, logs, Path(tmp) / "results", defaults)
                       for _ in range(args.repeat))
            base = base or best
            print(f"{label:<36} {best:7.2f} s  {args.files / best:7.1f} logs/s  "
                  f"{size / 1e6 / best:6.2f} MB/s  x{base / best:.2f} of local")


if __name__ == "__main__":
    main()

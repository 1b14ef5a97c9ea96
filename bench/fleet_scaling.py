"""Fleet scaling on one machine, in one run (issue 25): does a fleet run use the cores?

    python bench/fleet_scaling.py --out scaling.json             # sized for 16 cores
    python bench/fleet_scaling.py --quick --out scaling.json     # 2 cores: 8 logs, N=2

Writes LOGS candump logs of FRAMES frames each (one generated vectorised with
bench/traffic.py and bench/generate.py, then copied: many equal logs), then times whole
commands, each as its own process, interleaved over --repeat rounds (best of them):

- `check LOGS --results DS --executor local:1 --force` and `local:N` (and local:2, 4, ...
  between them: the scaling ladder);
- `check LOGS -j N` (no dataset) and `xargs -P N` of independent `nmtcheck check` runs
  (NMTCHECK_THREADS=1: one core each, as a fleet worker uses);
- the machine's ceiling: N copies of a fixed CPU-bound Python loop at once against one;
- `--executor dask-local:N --force`, its cluster start-up reported apart;
- `--executor dask://127.0.0.1:PORT --force` on a running loopback cluster the bench starts
  as docs/guides/fleet.md says (`dask scheduler`, `dask worker ADDRESS --nworkers N
  --nthreads 1`, Dask's default settings otherwise), after one untimed run (its first run,
  which sets the workers up, is reported apart); stopped at the end;
- start-up: `nmtcheck check` on a small log, and one log alone.

Prints a table (wall time, speed-up over local:1, fraction of the ceiling) and the ratios
issue 25 asks for, the driver's own CPU and the bytes it pickles per log, and writes it all
as JSON to --out. Needs only the project's virtual environment (numpy, pyarrow, and Dask
for the Dask rows: --no-dask without it); no network. On a loaded machine compare the
ratios of one round (the same round's commands ran under about the same load): the
`dask://` row's ratio to `local:N` is also given as the median of the rounds' ratios.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PY = sys.executable
LOOP = "s = 0\nfor i in range({n}):\n    s += i * i\n"
CLUSTER = "dask:// (running cluster)"

# Run inside the measured process: the CLI as `nmtcheck check` runs it, plus what the
# fleet run's outcome says about its driver (CPU, executor start) and the bytes the driver
# pickles per batch (sizes measured after the run's own timing, so not counted in it).
FLEET_WRAPPER = r"""
import sys
import nmtcheck.fleet.prestart  # as the command (this script is named nmtcheck) does first
import json, os, pickle, time
from nmtcheck.fleet import run as fleet_run
from nmtcheck.fleet import tasks as fleet_tasks
stats = {"sent": 0, "received": 0, "batches": 0}
sizes = []
submit = fleet_run._Dispatch.submit
def counting_submit(self, files):
    submit(self, files)
    sizes.append((files, self.shared_cfg))
fleet_run._Dispatch.submit = counting_submit
add = fleet_tasks.BatchCounts.add
received = []
def counting_add(self, other):
    received.append(other)
    add(self, other)
fleet_tasks.BatchCounts.add = counting_add
run_fleet = fleet_run.run_fleet
def recording_run_fleet(*args, **kwargs):
    out = run_fleet(*args, **kwargs)
    stats.update(seconds=out.seconds, start_seconds=out.start_seconds,
                 driver_cpu=out.driver_cpu, files=out.files, checked=out.checked,
                 executor=out.executor)
    return out
fleet_run.run_fleet = recording_run_fleet
def dump_stats():
    stats["batches"] = len(sizes)
    stats["sent"] = sum(len(pickle.dumps((fleet_tasks.check_batch, f, c))) for f, c in sizes)
    stats["received"] = sum(len(pickle.dumps(r)) for r in received)
    with open(os.environ["NMTCHECK_BENCH_STATS"], "w") as f:
        json.dump(stats, f)
import atexit
atexit.register(dump_stats)  # the command ends through its atexit handlers (cli.command)
from nmtcheck.cli.main import command
sys.argv = ["nmtcheck", *sys.argv[1:]]
command()
"""


def env(**extra: str) -> dict[str, str]:
    """The environment of every measured command: this checkout first on the path."""
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [e.get("PYTHONPATH")])])
    e.update(extra)
    return e


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed(cmd: list[str], ok: tuple[int, ...] = (0, 1), **kw: Any) -> tuple[float, float]:
    """Wall and CPU seconds (the process and every descendant it waited for)."""
    cpu = children_cpu()
    started = time.perf_counter()
    res = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         **kw)
    wall = time.perf_counter() - started
    if res.returncode not in ok:
        raise SystemExit(f"{' '.join(cmd[:6])} ...: exit {res.returncode}\n{res.stderr[-2000:]}")
    return wall, children_cpu() - cpu


def make_logs(root: Path, n_logs: int, frames: int) -> tuple[list[str], int]:
    """n_logs equal candump logs of `frames` frames; their paths and one's size."""
    sys.path.insert(0, str(HERE))
    from generate import candump_lines
    from traffic import traffic

    root.mkdir(parents=True, exist_ok=True)
    first = root / "log000.log"
    with open(first, "wb") as out:
        for chunk in traffic(frames):
            out.write(candump_lines(chunk))
    paths = [first]
    for i in range(1, n_logs):
        dest = root / f"log{i:03d}.log"
        shutil.copyfile(first, dest)
        paths.append(dest)
    return [str(p) for p in paths], first.stat().st_size


def calibrate_loop(target_s: float) -> int:
    """Iterations of LOOP that take about target_s in one process."""
    n = 200_000
    while True:
        started = time.perf_counter()
        exec(LOOP.format(n=n), {})
        took = time.perf_counter() - started
        if took > 0.05:
            return max(1, int(n * target_s / took))
        n *= 4


def ceiling(workers: int, iterations: int) -> dict[str, float]:
    """The speed-up N independent CPU-bound processes get here: N copies of the loop at
    once against one copy (each a fresh interpreter, so start-up is in both)."""
    code = LOOP.format(n=iterations)
    one, _ = timed([PY, "-S", "-c", code])
    started = time.perf_counter()
    procs = [subprocess.Popen([PY, "-S", "-c", code]) for _ in range(workers)]
    for p in procs:
        p.wait()
    many = time.perf_counter() - started
    return {"one_s": one, "n_s": many, "speedup": workers * one / many}


def ceiling_of(runs: list[dict[str, float]], workers: int) -> float:
    """The ceiling of the whole run, measured as the commands are (each timing the best of
    the rounds): N x the best one-copy time / the best N-copy time, and never over N. The
    best of the rounds' own ratios would pick the round whose noise favoured it most (a
    one-copy run slowed down by another job gives 2.13 on 2 cores)."""
    one = min(r["one_s"] for r in runs)
    many = min(r["n_s"] for r in runs)
    return min(float(workers), workers * one / many)


def fleet_cmd(logs_glob: str, results: Path, executor: str) -> list[str]:
    """The fleet run as a user starts it: FLEET_WRAPPER as a script named `nmtcheck`, as
    pip's console script runs (a __main__ with a file, which multiprocessing treats apart
    from `python -c` and `python -m`), so its workers start as the command's do."""
    script = results.parent / "bin" / "nmtcheck"
    script.parent.mkdir(parents=True, exist_ok=True)
    script.write_text(FLEET_WRAPPER)
    return [PY, str(script), "check", logs_glob, "--results", str(results),
            "--executor", executor, "--force", "-q", "--isolated"]


def run_fleet(cmd: list[str], stats_file: Path) -> tuple[float, float, dict[str, Any]]:
    trace = stats_file.with_suffix(".trace")
    trace.unlink(missing_ok=True)
    launched = time.time()
    wall, cpu = timed(cmd, env=env(NMTCHECK_BENCH_STATS=str(stats_file),
                                   NMTCHECK_FLEET_TRACE=str(trace)))
    stats = json.loads(stats_file.read_text())
    stats["phases"] = phases([json.loads(line) for line in trace.read_text().splitlines()],
                             launched, wall)
    return wall, cpu, stats


def phases(marks: list[dict[str, Any]], launched: float, wall: float) -> dict[str, Any]:
    """Where a fleet run's time went (nmtcheck/fleet/trace.py marks): seconds from the
    driver's launch to each of its phases, to the fork server's preload and to the first
    and last task; each worker's time between its tasks and in its Parquet writes."""
    driver = {m["phase"]: m for m in marks if m["phase"] in (
        "prestart", "cli", "run_fleet", "warm_up", "ensure", "lock", "skip_list",
        "listed_first", "dask_connected", "dask_versions", "dask_plugin", "dask_info",
        "executor", "drained", "closed", "run_row", "run_end", "reported")}
    at = {k: m["t"] - launched for k, m in driver.items()}
    results = [m["t"] for m in marks if m["phase"] == "results"]
    if results:
        at["first_result"] = min(results) - launched
    for name in ("preload_start", "preload"):
        ts = [m["t"] for m in marks if m["phase"] == name]
        if ts:
            at[name] = min(ts) - launched
    starts = [m["t"] for m in marks if m["phase"] == "task_start"]
    ends = [m["t"] for m in marks if m["phase"] == "task_end"]
    if starts:
        at["first_task"] = min(starts) - launched
        at["last_task_end"] = max(ends) - launched
        # every worker busy: the latest of the workers' first task starts (the pool forks
        # its workers one after the other)
        firsts: dict[int, float] = {}
        for m in marks:
            if m["phase"] == "task_start":
                firsts[m["pid"]] = min(firsts.get(m["pid"], m["t"]), m["t"])
        at["all_busy"] = max(firsts.values()) - launched
    at["exit"] = wall
    by_pid: dict[int, list[dict[str, Any]]] = {}
    for m in marks:
        by_pid.setdefault(m["pid"], []).append(m)
    writes = []
    busy = []
    first_tasks: list[float] = []
    later_tasks: list[float] = []
    for ms in by_pid.values():
        t = {}
        for m in ms:
            if m["phase"] == "checked":
                t["checked"] = m["t"]
            elif m["phase"] == "written" and "checked" in t:
                writes.append(m["t"] - t.pop("checked"))
        s = [m["t"] for m in ms if m["phase"] == "task_start"]
        e = [m["t"] for m in ms if m["phase"] == "task_end"]
        if s and e:
            busy.append(max(e) - min(s))
        # each task's duration, a worker's first apart (cold: its pages not yet touched)
        spans = sorted(zip(sorted(s), sorted(e), strict=False))
        for i, (t0, t1) in enumerate(spans):
            (first_tasks if i == 0 else later_tasks).append(t1 - t0)
    cpu = {k: m["cpu"] for k, m in driver.items()}
    return {"at": at, "writes_s": writes, "worker_span_s": busy,
            "first_task_s": first_tasks, "later_task_s": later_tasks,
            "driver_cpu_run_s": cpu.get("run_end", 0) - cpu.get("run_fleet", 0),
            # from the executor made (a Dask cluster started) to the run's end: per log
            "driver_cpu_after_start_s": cpu.get("run_end", 0) - cpu.get("executor", 0),
            "driver_cpu_to_cli_s": cpu.get("cli")}


def check_seconds(results: Path) -> list[float]:
    """Per log, the seconds its check took inside its worker (the inputs table)."""
    import pyarrow.dataset as pads

    t = pads.dataset(str(results / "inputs"), format="parquet", partitioning="hive")
    rows = t.to_table(columns=["seconds", "frames"]).to_pylist()
    return [r["seconds"] for r in rows if r["frames"]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", "-N", type=int, default=None,
                    help="N (default: the usable CPUs; 2 with --quick)")
    ap.add_argument("--logs", type=int, default=None, help="logs (default 32; 8 with --quick)")
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames per log")
    ap.add_argument("--repeat", type=int, default=None,
                    help="rounds, best of them (default 3; 2 with --quick)")
    ap.add_argument("--quick", action="store_true", help="a 2-core machine: 8 logs, N=2")
    ap.add_argument("--no-dask", action="store_true",
                    help="leave out dask-local:N and the running cluster")
    ap.add_argument("--no-cluster", action="store_true",
                    help="leave out the running cluster (dask://)")
    ap.add_argument("--no-ladder", action="store_true",
                    help="only local:1 and local:N (not local:2, 4, ... between them)")
    ap.add_argument("--dir", type=Path, default=None,
                    help="where the logs and datasets go (default: a temporary directory)")
    ap.add_argument("--out", type=Path, required=True, help="write the results as JSON here")
    args = ap.parse_args()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    n = args.workers or (2 if args.quick else usable)
    n_logs = args.logs or (8 if args.quick else 32)
    repeat = args.repeat or (2 if args.quick else 3)
    with_dask = not args.no_dask
    if with_dask:
        try:
            import distributed  # noqa: F401
        except ImportError:
            print("Dask is not installed: dask-local left out", file=sys.stderr)
            with_dask = False

    tmp = Path(tempfile.mkdtemp(prefix="nmtcheck-scaling-", dir=args.dir))
    try:
        report = measure(tmp, n, n_logs, args.frames, repeat, with_dask,
                         ladder=not args.no_ladder, usable=usable,
                         cluster=with_dask and not args.no_cluster)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nJSON: {args.out}")


def measure(tmp: Path, n: int, n_logs: int, frames: int, repeat: int, with_dask: bool,
            ladder: bool, usable: int, cluster: bool = False) -> dict[str, Any]:
    with contextlib.ExitStack() as stack:
        address = stack.enter_context(running_cluster(tmp / "cluster", n)) if cluster else None
        return _measure(tmp, n, n_logs, frames, repeat, with_dask, ladder, usable, address)


@contextlib.contextmanager
def running_cluster(where: Path, n: int) -> Iterator[str]:
    """A Dask scheduler on loopback and N single-threaded worker processes, started as
    docs/guides/fleet.md says (no setting beyond the command lines); the scheduler's
    address. Stopped (the bench's own processes, by their process groups) at the end."""
    dask = Path(PY).with_name("dask")
    where.mkdir(parents=True, exist_ok=True)
    info = where / "scheduler.json"
    log = open(where / "cluster.log", "wb")  # noqa: SIM115 - closed below
    e = env(DASK_TEMPORARY_DIRECTORY=str(where))
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--dashboard-address", ":0", "--scheduler-file", str(info)],
                              stdout=log, stderr=log, env=e, start_new_session=True)]
    try:
        deadline = time.monotonic() + 120
        while not info.exists():
            if time.monotonic() > deadline or procs[0].poll() is not None:
                raise SystemExit(f"dask scheduler did not start: see {where / 'cluster.log'}")
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        procs.append(subprocess.Popen([str(dask), "worker", address, "--nworkers", str(n),
                                       "--nthreads", "1", "--dashboard-address", ":0"],
                                      stdout=log, stderr=log, env=e, start_new_session=True))
        subprocess.run([PY, "-c", "import sys, distributed\n"
                        "with distributed.Client(sys.argv[1], timeout='60s') as c:\n"
                        "    c.wait_for_workers(int(sys.argv[2]), timeout=300)\n",
                        address, str(n)], check=True, env=e, timeout=400)
        yield address
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
        log.close()


def _measure(tmp: Path, n: int, n_logs: int, frames: int, repeat: int, with_dask: bool,
             ladder: bool, usable: int, address: str | None) -> dict[str, Any]:
    began = time.time()
    load_before = os.getloadavg()
    started = time.perf_counter()
    sys.path.insert(0, str(HERE))
    from bytecode import ensure_bytecode

    compiled = ensure_bytecode()
    paths, size = make_logs(tmp / "logs", n_logs, frames)
    generate_s = time.perf_counter() - started
    glob = str(tmp / "logs" / "*.log")
    print(f"{n_logs} candump logs of {frames:,} frames ({size / 1e6:.0f} MB each, written in "
          f"{generate_s:.1f} s); N={n} of {usable} usable CPUs; {platform.machine()}, "
          f"Python {platform.python_version()}, load {load_before[0]:.2f}; best of {repeat}; "
          f"{compiled}")

    small = tmp / "small.log"
    shutil.copyfile(REPO / "samples" / "healthy.log", small)
    nmt = [PY, "-m", "nmtcheck"]
    one_thread = env(NMTCHECK_THREADS="1")
    iterations = calibrate_loop(1.0)
    steps = sorted({1, n, *([k for k in (2, 4, 8, 16, 32, 64) if k < n] if ladder else [])})

    commands: dict[str, Any] = {}
    for k in steps:
        commands[f"local:{k}"] = ("fleet", fleet_cmd(glob, tmp / f"ds-local{k}", f"local:{k}"))
    cluster_first: dict[str, Any] = {}
    if address is not None:  # right after local:N: on a loaded machine, a round's two
        # neighbours ran under about the same load (their ratio is the figure to read)
        remote = "dask://" + address.removeprefix("tcp://")
        commands[CLUSTER] = ("fleet", fleet_cmd(glob, tmp / "ds-cluster", remote))
        # the cluster's first run registers nmtcheck's settings and imports on its workers
        wall, _cpu, st = run_fleet(commands[CLUSTER][1], tmp / "stats.json")
        cluster_first = {"wall_s": wall, "phases": st["phases"]}
        print(f"running cluster {address}: {n} workers; its first run (not timed below, it "
              f"sets the workers up) took {wall:.2f} s", flush=True)
    commands[f"check -j {n}"] = ("plain", [*nmt, "check", *paths, "-j", str(n), "-q",
                                           "--isolated"])
    xargs = shutil.which("xargs")
    xargs_cmd = ([xargs, "-P", str(n), "-n", "1", *nmt, "check", "-q", "--isolated"]
                 if xargs else None)
    commands[f"xargs -P{n}"] = ("xargs", xargs_cmd)
    if with_dask:
        commands[f"dask-local:{n}"] = ("fleet", fleet_cmd(glob, tmp / "ds-dask",
                                                          f"dask-local:{n}"))

    walls: dict[str, list[float]] = {name: [] for name in commands}
    cpus: dict[str, list[float]] = {name: [] for name in commands}
    fleet_stats: dict[str, list[dict[str, Any]]] = {}
    ceilings: list[dict[str, float]] = []
    startup: list[float] = []
    one_log: list[float] = []
    for rnd in range(repeat):
        ceilings.append(ceiling(n, iterations))
        startup.extend(timed([*nmt, "check", str(small), "-q", "--isolated"])[0]
                       for _ in range(5))
        one_log.append(timed([*nmt, "check", paths[0], "-q", "--isolated"], env=one_thread)[0])
        for name, (kind, cmd) in commands.items():
            if kind == "fleet":
                wall, cpu, st = run_fleet(cmd, tmp / "stats.json")
                fleet_stats.setdefault(name, []).append(st)
            elif kind == "xargs":
                if cmd is None:
                    wall, cpu = _xargs_python(nmt, paths, n, one_thread)
                else:
                    cpu0, t0 = children_cpu(), time.perf_counter()
                    subprocess.run(cmd, input="\n".join(paths), text=True, env=one_thread,
                                   stdout=subprocess.DEVNULL, check=False)
                    wall, cpu = time.perf_counter() - t0, children_cpu() - cpu0
            else:
                wall, cpu = timed(cmd, env=env())
            walls[name].append(wall)
            cpus[name].append(cpu)
        print(f"  round {rnd + 1}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in walls.items())
              + f"; ceiling x{ceilings[-1]['speedup']:.2f}", flush=True)

    per_log = check_seconds(tmp / "ds-local1")
    per_log_by = {name: check_seconds(tmp / ds) for name, ds in (
        (f"local:{n}", f"ds-local{n}"), (f"dask-local:{n}", "ds-dask"), (CLUSTER, "ds-cluster"))
        if (tmp / ds / "inputs").exists()}
    return summarise(locals())


def _xargs_python(nmt: list[str], paths: list[str], n: int, environ: dict[str, str]
                  ) -> tuple[float, float]:
    """`xargs -P n -n 1` where there is no xargs: n processes at a time."""
    cpu0, t0 = children_cpu(), time.perf_counter()
    running: list[subprocess.Popen[bytes]] = []
    for p in paths:
        while len(running) >= n:
            running = [r for r in running if r.poll() is None]
            time.sleep(0.005)
        running.append(subprocess.Popen([*nmt, "check", p, "-q", "--isolated"], env=environ,
                                        stdout=subprocess.DEVNULL))
    for r in running:
        r.wait()
    return time.perf_counter() - t0, children_cpu() - cpu0


PHASES = (("prestart", "driver: fork server started (prestart)"),
          ("cli", "driver: command line parsed, imports done"),
          ("run_fleet", "driver: run begins"), ("lock", "driver: dataset ensured, locked"),
          ("listed_first", "driver: first log listed, executor starts"),
          ("dask_connected", "driver: Dask imported, client connected"),
          ("dask_versions", "driver: versions checked (Dask's, nmtcheck's)"),
          ("dask_plugin", "driver: worker settings registered (plugin)"),
          ("dask_info", "driver: worker settings read back"),
          ("executor", "driver: executor made"),
          ("preload_start", "fork server: interpreter up, preload begins"),
          ("preload", "fork server: preload done"), ("first_task", "first task starts"),
          ("all_busy", "every worker has started its first task"),
          ("first_result", "driver: first result in"),
          ("last_task_end", "last task ends"), ("drained", "driver: every result in"),
          ("run_row", "driver: pool closed, run row written"), ("exit", "process exit"))


def print_phases(fleet_stats: dict[str, list[dict[str, Any]]]) -> None:
    """Median seconds from launch to each phase, per fleet command (the trace's marks)."""
    names = [n for n in fleet_stats if all("phases" in s for s in fleet_stats[n])]
    if not names:
        return
    print("\n| phase (median s from launch) | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for key, label in PHASES:
        cells = []
        for n in names:
            vals = [s["phases"]["at"][key] for s in fleet_stats[n] if key in s["phases"]["at"]]
            cells.append(f"{statistics.median(vals):.3f}" if vals else "")
        print(f"| {label} | " + " | ".join(cells) + " |")
    for n in names:
        runs = [s["phases"] for s in fleet_stats[n]]
        writes = [w for r in runs for w in r["writes_s"]]
        tail = [r["at"]["exit"] - r["at"]["last_task_end"] for r in runs
                if "last_task_end" in r["at"]]
        if not all("first_task" in r["at"] for r in runs):  # a run without a task's trace
            continue
        first = statistics.median(r["at"]["first_task"] for r in runs)
        nan = float("nan")
        firsts = [t for r in runs for t in r.get("first_task_s", [])]
        laters = [t for r in runs for t in r.get("later_task_s", [])]
        if firsts:
            print(f"{n}: a task takes {statistics.median(firsts):.3f} s as its worker's first, "
                  + (f"{statistics.median(laters):.3f} s later" if laters else "none later")
                  + " (medians)")
        print(f"{n}: fixed cost = first task {first:.3f} s + tail "
              f"{statistics.median(tail) if tail else nan:.3f} s (last task end to exit); "
              f"worker writes {1e3 * statistics.median(writes) if writes else nan:.1f} ms "
              f"per task; driver CPU in run_fleet "
              f"{1e3 * min(r['driver_cpu_run_s'] for r in runs):.1f} ms")


def summarise(m: dict[str, Any]) -> dict[str, Any]:
    n, walls, cpus = m["n"], m["walls"], m["cpus"]
    best = {k: min(v) for k, v in walls.items()}
    ceil = ceiling_of(m["ceilings"], n)
    base = best["local:1"]
    local_n = best[f"local:{n}"]
    plain = [best[k] for k in (f"check -j {n}", f"xargs -P{n}")]
    print(f"\n| command | wall (best of {m['repeat']}) | all runs | speed-up vs local:1 "
          "| fraction of ceiling |")
    print("|---|---:|---|---:|---:|")
    rows = []
    for name, w in best.items():
        label = {f"check -j {n}": f"`check -j {n}` (no dataset)",
                 f"xargs -P{n}": f"`xargs -P{n}` of `nmtcheck check` (NMTCHECK_THREADS=1)",
                 CLUSTER: f"`--executor dask://…` on a running {n}-worker loopback cluster"}.get(
            name, f"`--results DS --executor {name} --force`")
        speed = base / w
        rows.append({"command": name, "best_s": w, "runs_s": walls[name],
                     "cpu_s": cpus[name], "speedup": speed, "of_ceiling": speed / ceil})
        print(f"| {label} | {w:.2f} s | {', '.join(f'{x:.2f}' for x in walls[name])} | "
              f"{speed:.2f}x | {speed / ceil:.2f} |")
    ceiling_runs = ", ".join(f"x{c['speedup']:.2f}" for c in m["ceilings"])
    print(f"| the machine's ceiling: {n} copies of a CPU-bound loop vs one | | "
          f"{ceiling_runs} | {ceil:.2f}x | 1.00 |")

    ratios: dict[str, Any] = {
        "local_n_over_local_1": base / local_n,
        "local_n_over_best_plain": local_n / min(plain),
        "local_n_of_ceiling": base / local_n / ceil,
    }
    dask_name = f"dask-local:{n}"
    if dask_name in best:
        starts = [s["start_seconds"] for s in m["fleet_stats"][dask_name]]
        net = [w - s for w, s in zip(walls[dask_name], starts, strict=True)]
        ratios.update(dask_start_s=starts, dask_without_start_s=min(net),
                      dask_over_local_n=min(net) / local_n,
                      dask_whole_over_local_n=best[dask_name] / local_n)
    if CLUSTER in best:
        per_round = [c / lo for c, lo in zip(walls[CLUSTER], walls[f"local:{n}"], strict=True)]
        ratios.update(cluster_over_local_n=best[CLUSTER] / local_n,
                      cluster_over_local_n_rounds=per_round,
                      cluster_over_local_n_median=statistics.median(per_round),
                      cluster_first_run_s=m["cluster_first"]["wall_s"])
    per_log = statistics.median(m["per_log"]) if m["per_log"] else float("nan")
    drivers = {}
    for name, runs in m["fleet_stats"].items():
        st = min(runs, key=lambda s: s["driver_cpu"])
        files = max(1, st["checked"])
        drivers[name] = {
            "driver_cpu_s": st["driver_cpu"], "driver_cpu_per_log_s": st["driver_cpu"] / files,
            "driver_cpu_per_log_of_check": st["driver_cpu"] / files / per_log,
            "driver_cpu_after_start_per_log_s": min(
                r["phases"]["driver_cpu_after_start_s"] for r in runs) / files,
            "sent_bytes_per_log": st["sent"] / files, "received_bytes_per_log":
                st["received"] / files, "batches": st["batches"],
            "start_seconds": st["start_seconds"]}
    print_phases(m["fleet_stats"])
    startup = m["startup"]
    print(f"\nratios: local:{n} {ratios['local_n_over_local_1']:.2f}x local:1 (goal >= "
          f"{0.9 * n:.1f}x where the ceiling allows), {ratios['local_n_of_ceiling']:.2f} of the "
          f"ceiling (goal >= 0.9); local:{n} / best of check -j and xargs = "
          f"{ratios['local_n_over_best_plain']:.3f} (goal <= 1.10)")
    if "dask_over_local_n" in ratios:
        print(f"dask-local:{n}: {best[dask_name]:.2f} s whole, cluster start-up "
              f"{min(ratios['dask_start_s']):.2f}-{max(ratios['dask_start_s']):.2f} s, without it "
              f"{ratios['dask_without_start_s']:.2f} s = {ratios['dask_over_local_n']:.2f}x "
              f"local:{n} (goal <= 1.2)")
    if "cluster_over_local_n" in ratios:
        print(f"dask:// on a running {n}-worker cluster: best {best[CLUSTER]:.2f} s = "
              f"{ratios['cluster_over_local_n']:.2f}x local:{n}'s best; per round "
              + ", ".join(f"{r:.2f}x" for r in ratios["cluster_over_local_n_rounds"])
              + f", median {ratios['cluster_over_local_n_median']:.2f}x (goal <= 1.2); the "
              f"cluster's first run (setting its workers up) {ratios['cluster_first_run_s']:.2f} s")
    print(f"a log's check in a worker: median {per_log:.3f} s (local:1's inputs.seconds); one "
          f"log alone as a whole process: {min(m['one_log']):.2f} s")
    for name, secs in m["per_log_by"].items():
        if secs:
            print(f"  in a worker of {name}: median {statistics.median(secs):.3f} s "
                  f"(the last round's {len(secs)} logs)")
    print(f"start-up, `nmtcheck check` on a small log: min {min(startup):.3f} s, median "
          f"{statistics.median(startup):.3f} s over {len(startup)} runs (goal < 0.25 s)")
    for name, d in drivers.items():
        print(f"driver of {name}: {d['driver_cpu_s']:.3f} s CPU in the run = "
              f"{1e3 * d['driver_cpu_per_log_s']:.1f} ms per log "
              f"({100 * d['driver_cpu_per_log_of_check']:.1f} % of a log's check), "
              f"{1e3 * d['driver_cpu_after_start_per_log_s']:.1f} ms once its executor ran "
              f"({100 * d['driver_cpu_after_start_per_log_s'] / per_log:.1f} %); pickles "
              f"{d['sent_bytes_per_log'] / 1e3:.1f} kB out, {d['received_bytes_per_log']:.0f} B "
              f"back per log; {d['batches']} batches")
    return {
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(m["began"])),
        "machine": {"usable_cpus": m["usable"], "cpu_count": os.cpu_count(),
                    "platform": platform.platform(), "machine": platform.machine(),
                    "processor": platform.processor(), "python": platform.python_version(),
                    "load_before": m["load_before"], "load_after": os.getloadavg()},
        "params": {"workers": n, "logs": m["n_logs"], "frames": m["frames"],
                   "log_bytes": m["size"], "repeat": m["repeat"],
                   "generate_s": m["generate_s"], "loop_iterations": m["iterations"]},
        "rows": rows, "ceiling": {"best": ceil, "runs": m["ceilings"]}, "ratios": ratios,
        "check_seconds_per_log_median": per_log, "one_log_s": m["one_log"],
        "check_seconds_by_executor": m["per_log_by"], "cluster_first_run": m["cluster_first"],
        "startup_small_log_s": startup, "drivers": drivers, "fleet_stats": m["fleet_stats"],
        "seconds": time.time() - m["began"],
    }


if __name__ == "__main__":
    main()

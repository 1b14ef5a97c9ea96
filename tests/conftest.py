"""Shared helpers: run candump text through the real reader and the whole pipeline."""

from __future__ import annotations

import contextlib
import dataclasses
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from nmtcheck.engine import check_input, select_rules
from nmtcheck.readers import InputStats, open_input
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.results import InputResult
from nmtcheck.settings.network import Network, load_network
from nmtcheck.settings.profiles import load_profile

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"  # the steering folder beside the checkout: not in a clone
CORPUS = SHARED / "corpus"
SAMPLES = REPO / "samples"
# Small copies of the few ../shared files the tests cannot do without, under the same
# relative paths (provenance and licences: tests/data/README.md).
DATA = REPO / "tests" / "data"

NO_CORPUS = ("needs the shared test corpus ../shared/corpus (logs, device files), which is not "
             "part of the repository (a fresh clone has no ../shared beside it)")
# For tests that go through the whole corpus (or files of it with no copy in tests/data).
needs_corpus = pytest.mark.skipif(not CORPUS.is_dir(), reason=NO_CORPUS)


def shared_path(rel: str) -> Path | None:
    """`../shared/<rel>` when that is there, else its copy `tests/data/<rel>`, else None."""
    for base in (SHARED, DATA):
        if (base / rel).exists():
            return base / rel
    return None


def _no_shared(rel: str) -> str:
    return (f"needs ../shared/{rel}, which is not part of the repository (a fresh clone has no "
            "../shared beside it) and has no copy in tests/data")


def shared_file(rel: str) -> Path:
    """`shared_path(rel)`, or skip the calling test, saying which file is missing."""
    path = shared_path(rel)
    if path is None:
        pytest.skip(_no_shared(rel))
    return path


def needs_shared(*rels: str) -> pytest.MarkDecorator:
    """Skip unless every `rel` is in ../shared or has a copy in tests/data."""
    missing = [rel for rel in rels if shared_path(rel) is None]
    return pytest.mark.skipif(bool(missing), reason=_no_shared(missing[0]) if missing else "")


def read_columns(path: Path | str, **kw: object) -> tuple[InputStats, dict[str, np.ndarray]]:
    """All frames of one input through the real reader, as whole columns (batches joined)."""
    opened = open_input(str(path), **kw)  # type: ignore[arg-type]
    batches = list(opened.batches)
    names = [f.name for f in dataclasses.fields(FrameBatch)]
    if not batches:
        cols = {n: np.empty(0) for n in names}
        cols["data"] = np.empty((0, 8), np.uint8)
        return opened.stats, cols
    return opened.stats, {n: np.concatenate([getattr(b, n) for b in batches]) for n in names}


def candump(lines: list[tuple[float, str]], channel: str = "can0") -> str:
    """candump -L text from (time, 'ID#DATA') pairs."""
    return "".join(f"({1000.0 + t:.6f}) {channel} {frame}\n" for t, frame in lines)


class Checker:
    def __init__(self, tmp_path: Path) -> None:
        self.tmp_path = tmp_path
        self.n = 0

    def run(self, text: str, select: str = "", ignore: str = "", profile: str = "default",
            network: str | None = None, suffix: str = ".log") -> InputResult:
        self.n += 1
        log = self.tmp_path / f"trace{self.n}{suffix}"
        log.write_text(text)
        net: Network | None = None
        if network is not None:
            netfile = self.tmp_path / f"net{self.n}.toml"
            netfile.write_text(network)
            net = load_network(str(netfile))
        prof = load_profile(profile)
        rules = select_rules(prof, [s for s in select.split(",") if s],
                             [s for s in ignore.split(",") if s])
        return check_input(str(log), 0, prof, rules, net)

    def findings(self, text: str, **kw: object) -> list[tuple[str, int | None, float]]:
        """(code, node, time offset rounded to 1 ms) of every finding."""
        res = self.run(text, **kw)  # type: ignore[arg-type]
        start = res.stats.start or 0.0
        return [(f.rule, f.node, round(f.time - start, 3)) for f in res.findings]


@pytest.fixture
def checker(tmp_path: Path) -> Checker:
    return Checker(tmp_path)


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """The real command line (`python -m nmtcheck`), run outside the checkout."""
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def assert_one_line_error(res: subprocess.CompletedProcess[str], *needles: str) -> None:
    """Exit 2 with one line on stderr naming what is wrong, never a traceback."""
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


@contextlib.contextmanager
def cluster_process(code: str, env: dict[str, str] | None = None) -> Iterator[str]:
    """A Dask cluster that `code` starts in a Python of its own, printing its scheduler's
    address, and closes when its standard input ends; the address. Out of this process:
    a Dask client leaves threads running for good, and these tests fork."""
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None and proc.stdin is not None
    try:
        yield proc.stdout.readline().strip()
    finally:
        proc.stdin.close()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()

"""Shared helpers: run candump text through the real reader and the whole pipeline."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from nmtcheck.engine import InputResult, check_input, select_rules
from nmtcheck.frames import FrameBatch
from nmtcheck.network import Network, load_network
from nmtcheck.profiles import load_profile
from nmtcheck.readers import InputStats, open_input

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
CORPUS = SHARED / "corpus"
SAMPLES = REPO / "samples"


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

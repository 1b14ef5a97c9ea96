"""Shared helpers: run candump text through the real reader and the whole pipeline."""

from __future__ import annotations

from pathlib import Path

import pytest

from nmtcheck.engine import InputResult, check_input, select_rules
from nmtcheck.network import Network, load_network
from nmtcheck.profiles import load_profile

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
CORPUS = SHARED / "corpus"
SAMPLES = REPO / "samples"


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

"""A short, bounded run of the coverage-guided fuzz target over every text reader
(fuzz/fuzz_reader.py, atheris). Skipped where atheris is not installed: it is not a test
dependency (it needs a compiler on some platforms); fuzz/README.md describes longer runs."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

pytestmark = pytest.mark.skipif(importlib.util.find_spec("atheris") is None,
                                reason="atheris is not installed (pip install atheris)")

TARGET = REPO / "fuzz" / "fuzz_reader.py"
RUNS = 600  # inputs: a few seconds, enough to pass every reader's main paths


def test_short_fuzz_run_of_every_text_reader_finds_nothing(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    corpus = tmp_path / "corpus"
    seeded = subprocess.run([sys.executable, str(TARGET), "--format=all", f"--seed={corpus}"],
                            env=env, capture_output=True, text=True, timeout=120)
    assert seeded.returncode == 0, seeded.stderr
    assert len(list(corpus.iterdir())) == 7  # a valid log of every text format
    res = subprocess.run([sys.executable, str(TARGET), "--format=all", f"-runs={RUNS}", "-seed=1",
                          f"-artifact_prefix={tmp_path}/", str(corpus)], env=env,
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    crashes = sorted(p.name for p in tmp_path.glob("crash-*"))
    assert res.returncode == 0 and not crashes, res.stderr[-3000:]
    assert f"Done {RUNS} runs" in res.stderr

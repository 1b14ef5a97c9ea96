"""The package builds as a user or a release would build it: a wheel and an sdist with no
setuptools warning, `twine check` passes, and the wheel carries the report templates and
the rule profiles (issue 26)."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

pytest.importorskip("build", reason="the `package` dependency group is not installed")
pytest.importorskip("twine", reason="the `package` dependency group is not installed")


def test_wheel_and_sdist_build_cleanly_and_pass_twine(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "build", "--outdir", str(tmp_path), str(REPO)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    log = out.stdout + out.stderr
    for needle in ("SetuptoolsDeprecationWarning", "BuildBackendWarning",
                   "is absent from the `packages` configuration"):
        assert needle not in log, needle
    dists = sorted((p.name for p in tmp_path.iterdir()), key=lambda n: n.endswith(".whl"))
    assert len(dists) == 2 and dists[0].endswith(".tar.gz") and dists[1].endswith(".whl"), dists
    twine = subprocess.run([sys.executable, "-m", "twine", "check", "--strict",
                            *(str(tmp_path / d) for d in dists)],
                           capture_output=True, text=True, timeout=300)
    assert twine.returncode == 0, twine.stdout + twine.stderr
    names = zipfile.ZipFile(tmp_path / dists[1]).namelist()
    for wanted in ("nmtcheck/reporters/templates/report.html.j2",
                   "nmtcheck/reporters/templates/report.js", "nmtcheck/rules/default.toml"):
        assert wanted in names, wanted

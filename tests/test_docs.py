"""The documentation site (docs/, mkdocs.yml) builds and its examples run.

* `mkdocs build --strict` passes (a broken link or a missing page fails it), every rule
  of the registry has its generated page and the CLI reference is generated;
* every ```sh block of README.md and docs/ marked `<!-- run: exit=N -->` is run against
  the samples, line by line, and each `nmtcheck` command must exit with N. The commands
  of one page run in order in a scratch folder of that page, where `samples/` (and the
  checkout's other folders) are the checkout's: what they write (`-o report.html`,
  `--results results`) stays there. `< FILE` at the end of a line is its standard input
  (else it has none);
* every ```python block marked `<!-- run: python -->` runs in a fresh interpreter from
  the repository root without an error. Blocks that need hardware or a server (a PCAN
  adapter, an S3 endpoint) are not marked.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

from nmtcheck.checks import RULES

DOCS = REPO / "docs"
MARKDOWN = [REPO / "README.md", *sorted(DOCS.rglob("*.md"))]
RUN = re.compile(r"<!-- run: exit=(\d+) -->\n```sh\n(.*?)\n```", re.DOTALL)
RUN_PYTHON = re.compile(r"<!-- run: python -->\n```python\n(.*?)\n```", re.DOTALL)
HAS_MKDOCS = all(importlib.util.find_spec(m) is not None
                 for m in ("mkdocs", "material", "mkdocs_click"))


def _examples() -> list[tuple[str, str, int]]:
    """(where, command line, expected exit code) of every marked example."""
    found: list[tuple[str, str, int]] = []
    for md in MARKDOWN:
        text = md.read_text(encoding="utf-8")
        for m in RUN.finditer(text):
            line_no = text.count("\n", 0, m.start()) + 1
            found.extend((f"{md.relative_to(REPO)}:{line_no}", cmd, int(m.group(1)))
                         for cmd in m.group(2).splitlines()
                         if cmd.strip() and not cmd.lstrip().startswith("#"))
    return found


EXAMPLES = _examples()


def test_examples_are_collected() -> None:
    assert len(EXAMPLES) >= 6
    assert any(where.startswith("README.md") for where, _, _ in EXAMPLES)


def _python_examples() -> list[tuple[str, str]]:
    found: list[tuple[str, str]] = []
    for md in MARKDOWN:
        text = md.read_text(encoding="utf-8")
        for m in RUN_PYTHON.finditer(text):
            line_no = text.count("\n", 0, m.start()) + 1
            found.append((f"{md.relative_to(REPO)}:{line_no}", m.group(1)))
    return found


PYTHON_EXAMPLES = _python_examples()


def test_python_examples_are_collected() -> None:
    assert PYTHON_EXAMPLES, "no ```python block is marked <!-- run: python -->"


@pytest.mark.parametrize(("where", "code"), PYTHON_EXAMPLES,
                         ids=[w for w, _ in PYTHON_EXAMPLES])
def test_python_example_runs(where: str, code: str) -> None:
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, (where, proc.stdout[-2000:], proc.stderr[-2000:])


LINKED = ("samples", "rules", "docs", "tests", "bench")  # in a page's scratch folder


@pytest.fixture(scope="module")
def page_folders() -> dict[str, Path]:
    """The scratch folder of each page whose commands ran so far."""
    return {}


def _page_folder(where: str, folders: dict[str, Path], factory: pytest.TempPathFactory
                 ) -> Path:
    page = where.rsplit(":", 1)[0]
    if page not in folders:
        folder = folders[page] = factory.mktemp("page")
        for name in LINKED:
            (folder / name).symlink_to(REPO / name, target_is_directory=True)
    return folders[page]


@pytest.mark.parametrize(("where", "cmd", "code"), EXAMPLES,
                         ids=[f"{w}:{c}" for w, c, _ in EXAMPLES])
def test_example_runs(where: str, cmd: str, code: int, page_folders: dict[str, Path],
                      tmp_path_factory: pytest.TempPathFactory) -> None:
    argv = shlex.split(cmd, comments=True)
    assert argv[0] == "nmtcheck", f"{where}: only nmtcheck commands are run: {cmd}"
    cwd = _page_folder(where, page_folders, tmp_path_factory)
    stdin: int | None = subprocess.DEVNULL
    source = None
    if len(argv) > 2 and argv[-2] == "<":
        source, argv = cwd / argv[-1], argv[:-2]
    with open(source, "rb") if source is not None else contextlib.nullcontext() as f:
        proc = subprocess.run([sys.executable, "-m", "nmtcheck", *argv[1:]], cwd=cwd,
                              stdin=f if f is not None else stdin, capture_output=True,
                              text=True, timeout=120)
    assert proc.returncode == code, (where, cmd, proc.stdout[-2000:], proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr


def test_readme_links_into_the_docs_exist() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\(((?:docs/|LICENSE)[^)#]*)", text)
    assert len(links) > 10
    for link in links:
        assert (REPO / link).exists(), link


def test_the_json_page_names_every_top_level_field() -> None:
    proc = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "--isolated",
                           "samples/heartbeat_loss.log", "--format", "json"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    report = json.loads(proc.stdout)
    page = (DOCS / "reference" / "json.md").read_text(encoding="utf-8")
    for key in report:
        assert f"`{key}" in page, key
    for key in report["findings"][0]:
        assert f"`{key}`" in page or f"`{key}[]`" in page, key


@pytest.mark.skipif(not HAS_MKDOCS, reason="mkdocs, mkdocs-material or mkdocs-click is not "
                    "installed (they are in the dev dependency group)")
def test_mkdocs_build_strict(tmp_path: Path) -> None:
    site = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q",
                           "-f", str(REPO / "mkdocs.yml"), "-d", str(site)],
                          cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    missing = [r.code for r in RULES
               if not (site / "reference" / "rules" / r.code / "index.html").is_file()]
    assert not missing, f"rules without a generated page: {missing}"
    h001 = (site / "reference" / "rules" / "H001" / "index.html").read_text("utf-8")
    assert "timeout_factor" in h001 and "Why it matters" in h001
    cli = (site / "reference" / "cli" / "index.html").read_text("utf-8")
    for command in ("nmtcheck check", "nmtcheck timeline", "nmtcheck rules", "nmtcheck monitor",
                    "--fail-on"):
        assert command in cli, command

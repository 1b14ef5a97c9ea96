"""Issue 38, an honest gate round 3: a directory never passes over a broken log (item 1),
usage and help as click prints them (4), a README tour that runs (5), line-numbered
pastes (6), a `[... snip ...]` note is no I005 (9), the progress bar (12), smaller CLI
and API points (13) and docs pages whose commands run (14)."""

from __future__ import annotations

import io
import json
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import click
import pytest
from conftest import REPO, SAMPLES, assert_one_line_error
from conftest import run_cli as run

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"
FORMATS = ("text", "concise", "json", "junit", "markdown", "github", "sarif", "csv", "html")


# 1. a directory never passes over a broken log ------------------------------------------

def _logs_folder(tmp_path: Path) -> Path:
    """A healthy log, 3 kB of garbage and an empty file named .log, and files that are
    plainly no logs."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "healthy.log").write_bytes(HEALTHY.read_bytes())
    (logs / "broken.log").write_bytes(random.Random(38).randbytes(3000))
    (logs / "empty.log").write_bytes(b"")
    (logs / "README.md").write_text("# what we recorded\n")
    (logs / "network.toml").write_text("[nodes.3]\nheartbeat_ms = 100\n")
    (logs / "notes.txt").write_text("node 3 was unplugged at about 5 s\n")
    return logs


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_directory_names_its_broken_logs_in_every_format(tmp_path: Path, fmt: str) -> None:
    _logs_folder(tmp_path)
    res = run("check", "-q", "logs/", "--format", fmt, cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    for name in ("logs/broken.log", "logs/empty.log"):
        assert name in res.stdout, (fmt, res.stdout)
        assert f"nmtcheck: {name}: " in res.stderr
    assert "Traceback" not in res.stderr


def test_quiet_still_counts_the_files_that_are_no_log(tmp_path: Path) -> None:
    _logs_folder(tmp_path)
    out = run("check", "-q", "logs/", cwd=tmp_path).stdout.splitlines()
    assert out[0] == "3 files below the directories given are no log (skipped)"
    doc = json.loads(run("check", "logs/", "--format", "json", cwd=tmp_path).stdout)
    assert doc["not_logs"] == ["logs/README.md", "logs/network.toml", "logs/notes.txt"]
    assert [(i["path"], i["error"] is None) for i in doc["inputs"]] == [
        ("logs/broken.log", False), ("logs/empty.log", False), ("logs/healthy.log", True)]


@pytest.mark.parametrize("name, content, is_input", [
    ("cut.csv", b"garbage, not a header\n", True),
    ("killed.log.gz", b"", True),
    ("frames.txt", b"what we saw\nnode 3 sent 702#05 twice\n", True),  # looks like frames
    ("README.txt", b"what we did on day 1\n", False),
    ("photo.jpg", bytes(range(256)), False),
])
def test_which_files_below_a_directory_are_inputs(tmp_path: Path, name: str, content: bytes,
                                                   is_input: bool) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "a.log").write_bytes(HEALTHY.read_bytes())
    (logs / name).write_bytes(content)
    res = run("check", "logs", "--format", "json", cwd=tmp_path)
    doc = json.loads(res.stdout)
    assert res.returncode == (2 if is_input else 0), res.stderr
    assert (f"logs/{name}" in [i["path"] for i in doc["inputs"]]) is is_input
    assert (doc["not_logs"] == [f"logs/{name}"]) is not is_input


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_below_a_directory_is_named_and_never_opened(tmp_path: Path) -> None:
    """Opening a FIFO waits for a writer: the check would hang. Links to a file already
    taken are not read twice."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "a.log").write_bytes(HB_LOSS.read_bytes())
    os.mkfifo(logs / "live.log")
    (logs / "same.log").symlink_to("a.log")
    os.link(logs / "a.log", logs / "b.log")
    res = run("check", "logs", "--format", "json", cwd=tmp_path)  # run_cli: 120 s timeout
    assert res.returncode == 1, res.stderr
    doc = json.loads(res.stdout)
    assert [i["path"] for i in doc["inputs"]] == ["logs/a.log"]
    assert doc["not_logs"] == ["logs/live.log"]
    text = run("check", "logs", cwd=tmp_path).stdout
    assert text.startswith("1 file below the directories given are no log (skipped): "
                           "logs/live.log (not a regular file)")


# 4. usage and help as click prints them ------------------------------------------------

def _commands(group: click.Group, prefix: tuple[str, ...] = ()
              ) -> list[tuple[str, ...]]:
    out = [prefix]
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            out += _commands(cmd, (*prefix, name))
        else:
            out.append((*prefix, name))
    return out


@pytest.mark.parametrize("args", [(), ("fleet",)], ids=["nmtcheck", "fleet"])
def test_a_group_without_a_command_prints_its_help(tmp_path: Path, args: tuple[str, ...]
                                                   ) -> None:
    res = run(*args, cwd=tmp_path)
    assert res.returncode == 2
    lines = res.stderr.splitlines()
    assert re.fullmatch(rf"Usage: (python -m )?{' '.join(('nmtcheck', *args))} \[OPTIONS\] "
                        r"COMMAND \[ARGS\]\.\.\.", lines[0]), lines[0]
    assert "Commands:" in lines and len(lines) > 8
    assert "\\x0a" not in res.stderr and not res.stderr.startswith("nmtcheck:")


def test_the_help_of_every_command(tmp_path: Path) -> None:
    from nmtcheck.cli.main import cli

    for args in _commands(cli):
        res = run(*args, "--help", cwd=tmp_path)
        assert res.returncode == 0, (args, res.stderr)
        out = res.stdout
        usage = out.splitlines()[0].replace("python -m nmtcheck", "nmtcheck")
        assert usage.startswith(f"Usage: {' '.join(('nmtcheck', *args))} "), (args, out)
        assert "\\x0a" not in out and out.count("\n") > 4, args
        if "Commands:" in out:  # no description cut short with `...`
            listed = out.split("Commands:\n", 1)[1].splitlines()
            assert listed and not any(line.rstrip().endswith("...") for line in listed), out
        options = out.split("Options:\n", 1)[1]
        assert "[LOGS]..." not in options and "[CODE]" not in options, (args, out)
    check = run("check", "--help", cwd=tmp_path).stdout
    section = check.split("Arguments:\n", 1)[1].split("\n\n", 1)[0]
    assert section.split()[0] == "LOGS" and "directories" in section and "standard input" in section


def test_the_follow_summary_prints_as_lines(tmp_path: Path) -> None:
    """Ctrl-C ends `check --follow FILE`; the summary's lines were one line of `\\x0a`."""
    now = time.time() - 2.0
    log = tmp_path / "grow.log"
    log.write_text("".join(f"({now + k * 0.1:.6f}) can0 703#05\n" for k in range(15)))
    proc = subprocess.Popen([sys.executable, "-m", "nmtcheck", "check", "--follow",
                             str(log)], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)  # read, and the heartbeat timeout after the last frame fired
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=60)
    lines = err.splitlines()
    ended = next(k for k, line in enumerate(lines) if line.startswith("nmtcheck: session ended"))
    assert lines[ended + 1].startswith("  after the last recorded frame:"), err
    assert "\\x0a" not in err


# 5. the README tour runs ----------------------------------------------------------------

def test_the_readme_tour_runs_or_says_its_names_are_yours() -> None:
    """Every README block of nmtcheck commands runs on the samples (marked: the docs test
    runs it) or says that its names are placeholders; the tour says how `nmtcheck` gets
    on the PATH, and the site can be previewed with the docs tools alone."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    blocks = list(re.finditer(r"```sh\n(.*?)\n```", text, re.DOTALL))
    tour = [b for b in blocks if re.search(r"^nmtcheck ", b.group(1), re.MULTILINE)]
    assert len(tour) >= 3
    for b in tour:
        before = text[:b.start()].rstrip().rsplit("\n\n", 1)[-1]
        assert "<!-- run: exit=" in before or "in place of the names" in before, before
    marked = [b for b in tour if "<!-- run: exit=" in text[:b.start()].rstrip()[-30:]]
    assert sum(len(b.group(1).splitlines()) for b in marked) >= 8
    assert "source .venv/bin/activate" in " ".join(text.split())
    docs_only = [line for line in text.splitlines() if "--group docs" in line]
    assert docs_only and "mkdocs serve" in docs_only[0] and "--group dev" not in docs_only[0]


# 6. line-numbered pastes ----------------------------------------------------------------

def _gutters(lines: list[str]) -> dict[str, str]:
    return {
        "grep-n": "".join(f"{k}:{line}" for k, line in enumerate(lines, 1)),
        "grep-n-space": "".join(f"{k}: {line}" for k, line in enumerate(lines, 1)),
        "cat-n": "".join(f"{k:6d}\t{line}" for k, line in enumerate(lines, 1)),
        "editor": "".join(f"{k:4d} | {line}" for k, line in enumerate(lines, 1)),
        "box": "".join(f"{k:3d}\u2502{line}" for k, line in enumerate(lines, 1)),
        "vim": "".join(f"{k:4d} {line}" for k, line in enumerate(lines, 1)),
    }


def _findings(tmp_path: Path, name: str) -> tuple[list[tuple[str, int | None]], dict[str, object]]:
    doc = json.loads(run("check", name, "--format", "json", cwd=tmp_path).stdout)
    return [(f["rule"], f["line"]) for f in doc["findings"]], doc["inputs"][0]


@pytest.mark.parametrize("style", list(_gutters([])))
def test_line_numbered_pastes_are_read(tmp_path: Path, style: str) -> None:
    lines = HB_LOSS.read_text().splitlines(keepends=True)
    (tmp_path / "plain.log").write_text("".join(lines))
    (tmp_path / "numbered.txt").write_text(_gutters(lines)[style], encoding="utf-8")
    want, plain = _findings(tmp_path, "plain.log")
    got, numbered = _findings(tmp_path, "numbered.txt")
    assert want == [("H001", 77)] and got == want  # the file's own line numbers
    assert (numbered["format"], numbered["frames"], numbered["skipped"]) == (
        plain["format"], plain["frames"], 0)


def test_the_unknown_format_error_quotes_the_line_that_looked_like_a_frame(tmp_path: Path
                                                                          ) -> None:
    (tmp_path / "x.log").write_text("what the tester saw\nnode 3: 702#05 twice, then\n")
    res = run("check", "x.log", cwd=tmp_path)
    assert_one_line_error(res, "x.log: unknown log format (supported: ",
                          "line 2 looks like a CAN frame", "`node 3: 702#05 twice, then`",
                          "candump writes `(1700000000.000000) can0 702#05`")
    (tmp_path / "y.log").write_text("hello\n   0702 1 05 zz\n")
    assert_one_line_error(run("check", "y.log", cwd=tmp_path), "line 2 looks like a CAN frame",
                          "`0702 1 05 zz`", "Vector ASC")
    (tmp_path / "z.log").write_text("no frames here\n")  # nothing to quote
    res = run("check", "z.log", cwd=tmp_path)
    assert_one_line_error(res, "unknown log format")
    assert "looks like" not in res.stderr


# 9. a note that frames were left out is no I005 ---------------------------------------

def test_a_snip_note_in_a_log_without_timestamps_is_no_warning(tmp_path: Path) -> None:
    lines = [re.sub(r"^\(\S+\) ", "", line) for line in HB_LOSS.read_text().splitlines()]
    text = "\n".join([*lines[:40], "[... snip ...]", *lines[60:]]) + "\n"
    (tmp_path / "pasted.log").write_text(text)
    rules, _inp = _findings(tmp_path, "pasted.log")
    assert [r for r, _line in rules] == ["I006"]  # order only; no I005
    report = run("check", "pasted.log", cwd=tmp_path).stdout
    assert "frames were left out at line 41 (a note such as `[snip]` or `...`)" in report
    stamped = HB_LOSS.read_text().splitlines()
    (tmp_path / "cut.log").write_text("\n".join([*stamped[:40], "[... snip ...]",
                                                 *stamped[60:]]) + "\n")
    res = run("check", "cut.log", "--fail-on", "warning", "--select", "I", cwd=tmp_path)
    assert res.returncode == 0, res.stdout  # the user's own edit fails no gate


# 12. the progress bar -----------------------------------------------------------------

class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_progress_bar_runs_while_no_frame_arrives() -> None:
    """A read done within the delay, then checks that take long: the bar was never drawn
    (tqdm draws on an update only), so a long check looked hung."""
    from nmtcheck.cli.check import ProgressBar

    term = _Terminal()
    bar = ProgressBar(1, file=term, delay=0.2)
    bar.start_input("big.log")
    bar.frames(4800)  # all frames read at once, before the delay
    time.sleep(1.5)  # the rules run: no more updates
    shown = term.getvalue()
    bar.close()
    assert "[1/1] big.log: 4.80k frames" in shown, shown


def test_the_progress_bar_leaves_the_forked_parse_on() -> None:
    """The bar's ticker is the only thread it starts (no tqdm monitor) and it pauses at a
    fork, so a large log is still parsed in a forked worker on a terminal; closed, it
    leaves no thread behind (a later fork in the same process is not refused)."""
    from nmtcheck.cli.check import ProgressBar
    from nmtcheck.readers import forked

    before = {t.name for t in threading.enumerate()}
    bar = ProgressBar(1, file=_Terminal(), delay=0.0)
    try:
        assert {t.name for t in threading.enumerate()} - before == {"nmtcheck-progress"}
        assert forked.available()
        for _ in range(20):  # forks while the ticker draws: the child never hangs
            pid = os.fork()
            if pid == 0:
                os._exit(0)
            assert os.waitpid(pid, 0)[1] == 0
            bar.frames(1000)
            time.sleep(0.03)
    finally:
        bar.close()
    assert {t.name for t in threading.enumerate()} == before


@pytest.mark.parametrize("environ, quiet, follow, tty, wanted", [
    ({"TERM": "xterm"}, False, False, True, True),
    ({"TERM": "xterm", "CI": "true"}, False, False, True, False),  # a CI log, even on a pty
    ({"TERM": "dumb"}, False, False, True, False),
    ({"TERM": "xterm"}, True, False, True, False),  # -q
    ({"TERM": "xterm"}, False, True, True, False),  # --follow: live lines on stderr
    ({"TERM": "xterm"}, False, False, False, False),  # a pipe, a file
])
def test_the_progress_bar_is_for_a_terminal_only(environ: dict[str, str], quiet: bool,
                                                 follow: bool, tty: bool, wanted: bool) -> None:
    from nmtcheck.cli.check import progress_wanted

    stream = _Terminal() if tty else io.StringIO()
    assert progress_wanted(stream, quiet, follow, environ) is wanted


# 13. smaller points -------------------------------------------------------------------

def test_rules_prints_text_on_a_terminal_and_markdown_when_asked(tmp_path: Path) -> None:
    text = run("rules", "H001", cwd=tmp_path).stdout
    assert "What it checks. N produces heartbeats" in text
    assert "**" not in text and "`" not in text
    assert "timeout_factor = 1.5" in text
    markdown = run("rules", "H001", "--format", "markdown", cwd=tmp_path).stdout
    assert "**What it checks.**" in markdown and "`timeout_factor` = 1.5" in markdown


def test_shell_completion_completes_files_and_is_documented(tmp_path: Path) -> None:
    env = {**os.environ, "_NMTCHECK_COMPLETE": "bash_complete",
           "COMP_WORDS": "nmtcheck check sam", "COMP_CWORD": "2"}
    code = "from nmtcheck.cli.main import cli; cli.main(prog_name='nmtcheck')"
    res = subprocess.run([sys.executable, "-c", code],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert res.stdout.splitlines() == ["file,sam"], res.stdout + res.stderr
    page = (REPO / "docs" / "reference" / "cli.md").read_text(encoding="utf-8")
    for shell in ("bash", "zsh", "fish"):
        assert f"_NMTCHECK_COMPLETE={shell}_source nmtcheck" in page


def test_the_api_start_utc_is_a_time_and_a_report_prints_short() -> None:
    import nmtcheck

    report = nmtcheck.check([HB_LOSS, SAMPLES / "healthy.asc"])
    assert str(report.inputs["start_utc"].dtype) == "datetime64[ns, UTC]"
    assert str(report.findings["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert report.inputs["start_utc"].iloc[0].year == 2026 and report.inputs[
        "start_utc"].isna().iloc[1]  # ASC: relative stamps
    shown = str(report)
    assert shown == repr(report) and "\n" not in shown and len(shown) < 300
    assert shown.startswith("<nmtcheck Report: FAIL (--fail-on error): 1 error, 0 warnings, "
                            "0 info in 2 inputs; findings: 1 row, timeline: ")


# 14. docs pages whose commands run ------------------------------------------------------

def test_the_stale_pages_say_what_the_tool_does_and_run_their_commands() -> None:
    """The docs test runs every marked block (tests/test_docs.py); these pages had none,
    or said what is no longer so."""
    guides, reference = REPO / "docs" / "guides", REPO / "docs" / "reference"
    benches = (guides / "benches.md").read_text(encoding="utf-8")
    dataset = (reference / "dataset.md").read_text(encoding="utf-8")
    field = (guides / "field-logs.md").read_text(encoding="utf-8")
    assert "A file argument is a usage" not in " ".join(benches.split())
    assert "`check --follow FILE` follows a file as it grows" in " ".join(benches.split())
    assert "has no `findings/` folder" not in " ".join(dataset.split())
    for page in (benches, dataset, field):
        assert "<!-- run: exit=" in page
    step4 = field.split("**4. Hand it on**", 1)[1]
    command = re.search(r"<!-- run: exit=1 -->\n```sh\n(.*?)\n```", step4, re.DOTALL)
    assert command is not None and "-o report.html" in command.group(1)

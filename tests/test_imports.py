"""The module structure others rely on: the subcommand modules never import the command line
module (no import circle: cli.py registers them on its group), and the split of model.py
keeps every name `from nmtcheck.timeline.model import X` gave before."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SUBCOMMAND_MODULES = ("nmtcheck.fleet.commands", "nmtcheck.live.command")

# Every public name nmtcheck.timeline.model defined before the tables moved to tables.py and
# node_events.py (commit 2bbb2a2, model.py of 1,031 lines).
MODEL_NAMES = (
    "NmtFrame", "Command", "QUERY_GROUP", "known_cs", "reset_cs", "NmtTable", "plain_rows",
    "CommandTable", "EcFrame", "EcTable", "Timeout", "ConfigWrite", "WriteTable",
    "NodeEvent", "EmcyTable", "SdoEventTable", "NodeEvents", "Interval", "IntervalTable",
    "NodeConfig", "NodeModel", "TimelineParams", "Master", "ChannelModel", "InputModel",
    "SentFrames",
)


def cli_imports(source: str) -> list[int]:
    """Lines of `source` that import nmtcheck.cli.main, at the top or inside a function."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            hit = any(a.name == "nmtcheck.cli.main" or a.name.startswith("nmtcheck.cli.main.")
                      for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            hit = node.module == "nmtcheck.cli.main" or (
                node.module == "nmtcheck" and any(a.name == "cli" for a in node.names))
        else:
            continue
        if hit:
            lines.append(node.lineno)
    return lines


def test_cli_imports_finds_lazy_and_top_level_imports() -> None:
    """The scan sees the forms the circle took (a lazy import inside a function) and no
    look-alike module (cli_common)."""
    source = ("import nmtcheck.cli.main\n"
              "from nmtcheck.cli.common import write_stdout\n"
              "def f():\n"
              "    from nmtcheck.cli.main import _load\n"
              "    from nmtcheck import cli, errors\n")
    assert cli_imports(source) == [1, 4, 5]
    assert cli_imports("from nmtcheck.cli.common import EXIT_OK\nimport nmtcheck.clicks\n") == []


@pytest.mark.parametrize("module", SUBCOMMAND_MODULES)
def test_subcommand_module_never_imports_cli(module: str) -> None:
    """Not at the top, not inside a function: what they share with cli.py is in
    cli_common.py."""
    path = REPO / (module.replace(".", "/") + ".py")
    assert cli_imports(path.read_text(encoding="utf-8")) == []


@pytest.mark.parametrize("module", SUBCOMMAND_MODULES)
def test_subcommand_module_loads_without_cli(module: str) -> None:
    """Imported alone in a fresh interpreter, nothing it imports pulls in nmtcheck.cli.main."""
    code = (f"import sys, {module}\n"
            "print('nmtcheck.cli.main' in sys.modules, 'nmtcheck.cli.common' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, check=True)
    loaded_cli, loaded_common = res.stdout.split()
    assert loaded_cli == "False"
    # live/command.py takes its helpers from cli_common at import; fleet/commands.py only
    # when `fleet summary -o` writes (it stays light: click only)
    assert loaded_common == ("True" if module == "nmtcheck.live.command" else "False")


def test_subcommands_registered_on_the_group() -> None:
    from nmtcheck.cli.main import cli
    from nmtcheck.fleet.commands import fleet
    from nmtcheck.live.command import monitor

    assert cli.commands["fleet"] is fleet
    assert cli.commands["monitor"] is monitor
    assert set(cli.commands) == {"check", "timeline", "rules", "fleet", "monitor"}


def test_cli_still_gives_the_moved_helpers() -> None:
    """`from nmtcheck.cli.main import write_reports` (tests, scripts) gives cli_common's."""
    from nmtcheck.cli.main import main as cli
    from nmtcheck.cli.main import common as cli_common

    for name in ("EXIT_OK", "EXIT_FINDINGS", "EXIT_ERROR", "resolve_settings",
                 "load_profile_network", "check_outputs", "write_atomically", "write_reports",
                 "write_stdout"):
        assert getattr(cli, name) is getattr(cli_common, name), name
    assert (cli.EXIT_OK, cli.EXIT_FINDINGS, cli.EXIT_ERROR) == (0, 1, 2)


def test_model_gives_every_name_it_gave_before() -> None:
    """The tables moved out are the same objects through nmtcheck.timeline.model (an isinstance
    check or a `field(default_factory=EcTable.empty)` sees one class, not two)."""
    from nmtcheck.timeline.build import model
    from nmtcheck.timeline.build import node_events
    from nmtcheck.timeline.build import tables

    missing = [name for name in MODEL_NAMES if not hasattr(model, name)]
    assert missing == []
    assert sorted(model.__all__) == sorted(MODEL_NAMES)
    for name in MODEL_NAMES:
        home = next((m for m in (tables, node_events) if hasattr(m, name)), model)
        assert getattr(model, name) is getattr(home, name), name
    assert tables.EcTable.__module__ == "nmtcheck.timeline.tables"
    assert node_events.WriteTable.__module__ == "nmtcheck.timeline.node_events"
    assert model.NodeModel(0, "can0", 1, model.NodeConfig()).ec.__class__ is tables.EcTable


def test_model_names_import_in_a_fresh_interpreter() -> None:
    """`from nmtcheck.timeline.model import X` for every name, as the other modules write it (no
    import circle between model.py and the table modules)."""
    code = f"from nmtcheck.timeline.model import {', '.join(MODEL_NAMES)}"
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr

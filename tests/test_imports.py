"""The module structure others rely on: one folder per stage, the data flowing down the
folder list; no import circle anywhere, type-only ones included; the subcommand modules
never import the command's group (cli/main.py registers them on it); and the split of
model.py keeps every name `from nmtcheck.timeline.model import X` gave before."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SUBCOMMAND_MODULES = ("nmtcheck.cli.fleet", "nmtcheck.cli.monitor")

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
    assert loaded_common == ("True" if module == "nmtcheck.cli.monitor" else "False")


def test_subcommands_registered_on_the_group() -> None:
    from nmtcheck.cli.fleet import fleet
    from nmtcheck.cli.main import cli
    from nmtcheck.cli.monitor import monitor

    assert cli.commands["fleet"] is fleet
    assert cli.commands["monitor"] is monitor
    assert set(cli.commands) == {"check", "timeline", "rules", "fleet", "monitor"}


def test_cli_still_gives_the_moved_helpers() -> None:
    """`from nmtcheck.cli.main import write_reports` (tests, scripts) gives cli_common's."""
    from nmtcheck.cli import common as cli_common
    from nmtcheck.cli import main as cli

    for name in ("EXIT_OK", "EXIT_FINDINGS", "EXIT_ERROR", "resolve_settings",
                 "load_profile_network", "check_outputs", "write_atomically", "write_reports",
                 "write_stdout"):
        assert getattr(cli, name) is getattr(cli_common, name), name
    assert (cli.EXIT_OK, cli.EXIT_FINDINGS, cli.EXIT_ERROR) == (0, 1, 2)


def test_model_gives_every_name_it_gave_before() -> None:
    """The tables moved out are the same objects through nmtcheck.timeline.model (an isinstance
    check or a `field(default_factory=EcTable.empty)` sees one class, not two)."""
    from nmtcheck.timeline import model, node_events, tables

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


PACKAGE = REPO / "nmtcheck"
# The stages in the order the data flows (read -> decode -> timeline -> rules -> findings
# -> report): a module imports from its own stage or one above it in this list, never from
# a later one. `spool`, `errors` and `safe_text` serve every stage.
STAGES = ("errors", "safe_text", "spool", "protocol", "readers", "timeline", "processes",
          "checks", "settings", "results", "explain", "engine", "reporters", "live", "fleet",
          "api", "cli", "__main__")
TOP_LEVEL_MODULES = {"__init__", "__main__", "api", "engine", "errors", "results",
                     "safe_text", "spool"}
MAX_LINES = 900


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(REPO).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the nmtcheck modules it imports, anywhere in it (under TYPE_CHECKING and
    inside functions too): a circle through a type-only import is still a circle."""
    modules = _modules()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            graph[name].update(t for t in targets if t in modules and t != name)
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_circles_finds_a_type_only_circle() -> None:
    """The check sees what it guards against: two modules importing each other."""
    assert circles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle() -> None:
    assert circles(import_graph()) == []


def _stage(module: str) -> int:
    parts = module.split(".")
    return STAGES.index(parts[1]) if len(parts) > 1 else len(STAGES)


def test_top_level_holds_only_the_stage_folders_and_the_entry_modules() -> None:
    top = {p.stem for p in PACKAGE.glob("*.py")}
    assert top == TOP_LEVEL_MODULES
    folders = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert folders == set(STAGES) - TOP_LEVEL_MODULES


def test_imports_follow_the_stages() -> None:
    """No stage imports a later one (`-j` in the engine runs on the fleet's resilient
    process pool, a lazy import: the one exception)."""
    allowed = {("nmtcheck.engine", "nmtcheck.fleet.executors")}
    upward = sorted((m, t) for m, targets in import_graph().items() for t in targets
                    if t != "nmtcheck" and _stage(t) > _stage(m) and (m, t) not in allowed)
    assert upward == []


def test_no_module_over_900_lines_without_a_reason() -> None:
    """A module past MAX_LINES says at its top why it stays whole."""
    long = [str(p.relative_to(REPO)) for p in _modules().values()
            if len(p.read_text(encoding="utf-8").splitlines()) > MAX_LINES
            and "stays whole" not in p.read_text(encoding="utf-8")[:3000]]
    assert long == []

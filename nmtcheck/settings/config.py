"""Configuration files (SPEC §5): `nmtcheck.toml`, or `[tool.nmtcheck]` in `pyproject.toml`.

Found as ruff and pytest find theirs: from the current directory upward, the first
directory that holds `nmtcheck.toml`, or a `pyproject.toml` with a `[tool.nmtcheck]`
table (`nmtcheck.toml` first when a directory has both), ends the search; so does a
repository root (a directory holding `.git`), after it has been looked at. A
`pyproject.toml` on that path that cannot be parsed stops the run (exit 2, naming file
and line), as in ruff and pytest, never skipped in silence. Command-line
options win over the file, key by key; `--isolated` ignores it.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError
from nmtcheck.settings.values import loads, quoted, shortened

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

CONFIG_NAME = "nmtcheck.toml"
PYPROJECT = "pyproject.toml"
FAIL_ON = ("error", "warning", "info", "never")
KEYS = ("rules", "network", "select", "ignore", "fail-on", "format", "timeline")


@dataclass
class Config:
    """What a configuration file sets; None: not set (the built-in default applies)."""

    path: Path
    label: str  # how errors name the table: `nmtcheck.toml` or `pyproject.toml [tool.nmtcheck]`
    profile: str | None = None  # `rules = "NAME"` or `[rules] extends = "NAME"`
    rule_tables: dict[str, Any] = field(default_factory=dict)  # [rules.CODE]
    timeline: dict[str, Any] = field(default_factory=dict)  # [timeline]
    network: str | None = None  # resolved against the file's directory
    select: list[str] | None = None
    ignore: list[str] | None = None
    fail_on: str | None = None
    format: str | None = None

    @property
    def directory(self) -> Path:
        return self.path.parent

    @property
    def has_profile_tables(self) -> bool:
        return bool(self.rule_tables or self.timeline)

    def display(self) -> str:
        """The file's path as reports show it: relative to the current directory."""
        try:
            return os.path.relpath(self.path)
        except ValueError:  # another drive (Windows)
            return str(self.path)


def find_config(start: Path | None = None) -> Path | None:
    """The configuration file that applies in `start` (default: the current directory)."""
    here = (start or Path.cwd()).resolve()
    for directory in (here, *here.parents):
        candidate = directory / CONFIG_NAME
        if candidate.is_file():
            return candidate
        pyproject = directory / PYPROJECT
        if pyproject.is_file() and _has_tool_table(pyproject):
            return pyproject
        if (directory / ".git").exists():
            return None  # a repository root: its parents belong to something else
    return None


def _has_tool_table(path: Path) -> bool:
    """Whether a pyproject.toml on the discovery path has `[tool.nmtcheck]`. One that cannot
    be parsed is an error naming its file and line, as in ruff and pytest: skipping it
    would silently check with another configuration (SPEC §4)."""
    tool = _parse(path).get("tool")
    return isinstance(tool, dict) and "nmtcheck" in tool


def _parse(path: Path) -> dict[str, Any]:
    """A TOML file's content; errors name the file (and line) it could not be read at."""
    try:
        data: dict[str, Any] = loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None) or _line_of(str(exc))
        where = f"{path}:{line}" if line else str(path)
        raise UsageError(f"{where}: invalid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise UsageError(f"{path}: cannot read: not UTF-8 text") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return data


def _line_of(message: str) -> int | None:
    """The line number in tomllib's message (`... (at line 3, column 9)`)."""
    found = re.search(r"at line (\d+)", message)
    return int(found.group(1)) if found else None


def _patterns(where: str, key: str, value: Any) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise UsageError(f"{where} {key}: expected a list of rule codes, prefixes or names, "
                         f"e.g. [\"H\", \"heartbeat-too-early\"]")
    return [v.strip() for item in value for v in item.split(",") if v.strip()]


def _string(where: str, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise UsageError(f"{where} {key}: expected a string, got {quoted(value)}")
    return value


def load_config(path: Path) -> Config:
    """Read one configuration file (`nmtcheck.toml`, or `pyproject.toml`'s
    `[tool.nmtcheck]`); errors name the file and key (exit 2)."""
    label, data = _read_table(path)
    where = f"{label}:"
    cfg = Config(path=path.resolve(), label=label)
    for key, value in data.items():
        if key not in KEYS:
            raise UsageError(f"{where} {shortened(key)}: unknown key (known: "
                             f"{', '.join(KEYS)})")
        _set(cfg, where, key, value)
    return cfg


def _read_table(path: Path) -> tuple[str, dict[str, Any]]:
    """The name to give the configuration in messages, and its table."""
    data = _parse(path)
    if path.name != PYPROJECT:
        return str(path), data
    tool = data.get("tool", {})
    table = tool.get("nmtcheck", {}) if isinstance(tool, dict) else {}
    label = f"{path} [tool.nmtcheck]"
    if not isinstance(table, dict):
        raise UsageError(f"{label}: expected a table")
    return label, table


def _set(cfg: Config, where: str, key: str, value: Any) -> None:
    """One known key of the configuration, checked."""
    if key == "rules":
        _set_rules(cfg, where, value)
    elif key == "timeline":
        if not isinstance(value, dict):
            raise UsageError(f"{where} timeline: expected a table [timeline]")
        cfg.timeline = value
    elif key == "network":
        cfg.network = str(cfg.directory / _string(where, key, value))
    elif key in ("select", "ignore"):
        setattr(cfg, key, _patterns(where, key, value))
    elif key == "fail-on":
        if value not in FAIL_ON:
            raise UsageError(f"{where} fail-on: expected one of {', '.join(FAIL_ON)}, "
                             f"got {quoted(value)}")
        cfg.fail_on = value
    elif key == "format":
        cfg.format = _string(where, key, value)


def _set_rules(cfg: Config, where: str, value: Any) -> None:
    """`rules = "PROFILE"`, or [rules] (`extends = "PROFILE"`) with [rules.CODE] tables."""
    if isinstance(value, str):
        cfg.profile = _string(where, "rules", value)
    elif isinstance(value, dict):
        tables = dict(value)
        base = tables.pop("extends", None)
        if base is not None:
            cfg.profile = _string(where, "[rules] extends", base)
        cfg.rule_tables = tables
    else:
        raise UsageError(f"{where} rules: expected a profile name or path, or "
                         f"[rules.CODE] tables")


def discover(explicit: str | None, isolated: bool) -> Config | None:
    """The configuration in force: `--config FILE`, else the one found upward from the
    current directory; none with `--isolated`."""
    if explicit is not None:
        if isolated:
            raise UsageError("--config and --isolated: use one or the other")
        path = Path(explicit)
        if not path.is_file():
            raise UsageError(f"--config {explicit}: no such file")
        return load_config(path)
    if isolated:
        return None
    found = find_config()
    return load_config(found) if found is not None else None

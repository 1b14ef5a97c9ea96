"""Rule profiles: TOML files in `rules/` (shipped in the wheel), `extends`, per-rule settings."""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.checks import BY_CODE
from nmtcheck.checks.base import SEVERITIES
from nmtcheck.errors import UsageError
from nmtcheck.settings.values import loads, number, quoted, shortened

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

DEFAULT_PROFILE = "default"


@dataclass
class RuleSettings:
    enabled: bool = True
    severity: str = ""
    params: dict[str, Any] = field(default_factory=dict)


# [timeline]: parameters of no single rule (the boot process and cause chains: SPEC §8)
TIMELINE_PARAMS = {"master_window_ms": 1000.0, "boot_probe_window_ms": 1000.0,
                   "sdo_timeout_ms": 1000.0, "causes_before_ms": 1000.0,
                   "causes_after_ms": 500.0, "causes_max": 5.0, "silence_min_ms": 100.0,
                   "reboot_cluster_ms": 500.0, "causes_depth_max": 3.0,
                   "emcy_delay_ms": 200.0, "lss_response_timeout_ms": 1000.0,
                   "timestamp_resolution_us": 0.0}


class Profile(dict[str, RuleSettings]):
    """Rule code -> settings, plus the `[timeline]` parameters (SPEC §5)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.timeline: dict[str, float] = dict(TIMELINE_PARAMS)


def registry_profile() -> Profile:
    """Every rule at the severity and parameters it declares: the base of every profile
    (rules/default.toml changes nothing of it; other profiles change what they need)."""
    return Profile({r.code: RuleSettings(True, r.severity, {p.name: p.default for p in r.params})
                    for r in BY_CODE.values()})


def builtin_dir() -> Path:
    """Where the shipped profiles are: package data when installed, `rules/` in a checkout."""
    here = Path(__file__).resolve().parent.parent  # the nmtcheck package
    installed = here / "rules"
    return installed if (installed / "default.toml").is_file() else here.parent / "rules"


def _default_path() -> Path:
    return (builtin_dir() / f"{DEFAULT_PROFILE}.toml").resolve()


def builtin_profiles() -> list[str]:
    return sorted(p.stem for p in builtin_dir().glob("*.toml"))


def _resolve(name: str, relative_to: Path | None) -> Path:
    candidates = []
    if relative_to is not None:
        candidates.append(relative_to / name)
        candidates.append(relative_to / f"{name}.toml")
    candidates.append(Path(name))
    if "/" not in name and "\\" not in name:
        candidates.append(builtin_dir() / (name if name.endswith(".toml") else f"{name}.toml"))
    for c in candidates:
        with contextlib.suppress(OSError):  # a name too long for a path: no such profile
            if c.is_file():
                return c
    raise UsageError(f"{shortened(name)}: no such rule profile "
                     f"(built in: {', '.join(builtin_profiles())})")


def _check_value(where: str, value: Any, want: type) -> Any:
    if want is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        # every numeric parameter is a time, factor or tolerance: finite, >= 0
        return float(number(where, value))
    if want is list and isinstance(value, list):
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise UsageError(f"{where}: expected a list of integers (CAN-IDs, e.g. 0x7E4)")
        return value
    if want is int and isinstance(value, int) and not isinstance(value, bool):
        return number(where, value, integer=True)
    if (isinstance(value, want) and not isinstance(value, bool)) or (want is bool
                                                                 and isinstance(value, bool)):
        return value
    raise UsageError(f"{where}: expected {want.__name__}, got {type(value).__name__} "
                     f"{quoted(value)}")


def load_profile(name: str = DEFAULT_PROFILE, _seen: tuple[Path, ...] = ()) -> Profile:
    """Read a profile and everything it extends; errors name the file and key."""
    path = _resolve(name, _seen[-1].parent if _seen else None)
    if path.resolve() in _seen:
        raise UsageError(f"{path}: 'extends' loops back to itself")
    try:
        data = loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{path}: invalid TOML: {exc}") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot read: {exc.strerror}") from None
    for key in data:
        if key not in ("extends", "rules", "timeline"):
            raise UsageError(f"{path}: unknown key {quoted(key)} "
                             f"(expected 'extends', [timeline] and [rules.CODE])")
    profile = registry_profile()
    # A profile without `extends` extends `default`, so a user file holds only its changes.
    base = data.get("extends", None if path.resolve() == _default_path() else DEFAULT_PROFILE)
    if base is not None:
        if not isinstance(base, str):
            raise UsageError(f"{path}: extends: expected a profile name or path")
        profile = load_profile(base, (*_seen, path.resolve()))
    apply_tables(profile, str(path), data.get("rules", {}), data.get("timeline", {}))
    return profile


def derived_profile(where: str, base: str, base_dir: Path, rules: Any,
                    timeline: Any = None) -> Profile:
    """A profile that extends `base` (a name, or a path relative to `base_dir`) with
    `[rules.CODE]` and `[timeline]` tables held elsewhere (a configuration file, `where`)."""
    try:
        profile = load_profile(base, (base_dir / "<configuration>",))
    except UsageError as exc:  # the profile it names is missing: name the file too
        if str(exc).startswith(f"{shortened(base)}: no such rule profile"):
            raise UsageError(f"{where}: rules: {exc}") from None
        raise
    apply_tables(profile, where, rules, {} if timeline is None else timeline)
    return profile


def apply_tables(profile: Profile, where: str, rules: Any, timeline: Any) -> None:
    """Apply a profile's `[timeline]` and `[rules.CODE]` tables; errors name `where`."""
    path = where
    if not isinstance(timeline, dict):
        raise UsageError(f"{path}: timeline: expected a table [timeline]")
    for key, value in timeline.items():
        if key not in TIMELINE_PARAMS:
            raise UsageError(f"{path}: [timeline] {shortened(key)}: unknown parameter "
                             f"(known: {', '.join(TIMELINE_PARAMS)})")
        profile.timeline[key] = _check_value(f"{path}: [timeline] {key}", value, float)
    if not isinstance(rules, dict):
        raise UsageError(f"{path}: rules: expected tables [rules.CODE]")
    for code, table in rules.items():
        rule = BY_CODE.get(code)
        if rule is None:
            raise UsageError(f"{path}: [rules.{shortened(code)}]: unknown rule code")
        if not isinstance(table, dict):
            raise UsageError(f"{path}: rules.{code}: expected a table")
        settings = profile.setdefault(code, RuleSettings(severity=rule.severity))
        params = {p.name: p for p in rule.params}
        for key, value in table.items():
            where_key = f"{path}: [rules.{code}] {shortened(key)}"
            if key == "enabled":
                settings.enabled = _check_value(where_key, value, bool)
            elif key == "severity":
                if value not in SEVERITIES:
                    raise UsageError(f"{where_key}: expected one of {', '.join(SEVERITIES)}")
                settings.severity = value
            elif key in params:
                settings.params[key] = _check_value(where_key, value, params[key].type)
                top = params[key].maximum
                if top is not None and settings.params[key] > top:
                    raise UsageError(f"{where_key}: expected a number from 0 to {top:g}, "
                                     f"got {quoted(value)}")
            else:
                known = ", ".join(["enabled", "severity", *params]) or "none"
                raise UsageError(f"{where_key}: unknown parameter (known: {known})")

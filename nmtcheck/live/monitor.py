"""`nmtcheck.Monitor`: a python-can Listener for test benches and hardware-in-the-loop
tests (`can.Notifier(bus, [monitor])`, then `assert monitor.findings(severity="error")
== []`).

`findings()` is `nmtcheck check` over what the monitor has recorded so far, plus the live
timeouts that have expired after the last recorded frame (a bus gone quiet would hide
them from any offline check). Thread-safe: the Notifier's thread feeds, the test reads.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import can

from nmtcheck.checks.base import SEVERITIES
from nmtcheck.engine import select_rules
from nmtcheck.errors import string_list
from nmtcheck.live.frames import from_message
from nmtcheck.live.session import Outcome, Session
from nmtcheck.live.tracker import LiveFinding, NodeState
from nmtcheck.reporters import renderer
from nmtcheck.results import Finding, InputResult
from nmtcheck.settings.network import Network, load_network
from nmtcheck.settings.profiles import DEFAULT_PROFILE, Profile, load_profile
from nmtcheck.timeline.model import Interval

MAX_ERRORS_KEPT = 10
ERROR_BACKOFF_S = 0.05  # after that many bus errors, each one waits this long


class Monitor(can.Listener):
    """Checks the frames a python-can Notifier hands it, live and (on demand) offline.

    network: a network file path or a loaded `Network`; rules: a profile name or path
    (or a loaded `Profile`); select/ignore: as `nmtcheck check --select/--ignore`;
    record: keep the recording (a candump log) at this path, else a temporary file
    removed by `stop()`; channel: the name of frames whose Message has no channel;
    on_finding: called (on the feeding or timer thread) with each live finding.
    """

    def __init__(self, network: str | os.PathLike[str] | Network | None = None,
                 rules: str | Profile = DEFAULT_PROFILE, select: list[str] | None = None,
                 ignore: list[str] | None = None, record: str | os.PathLike[str] | None = None,
                 channel: str = "can0",
                 on_finding: Callable[[LiveFinding], Any] | None = None) -> None:
        self.profile = rules if isinstance(rules, Profile) else load_profile(rules)
        self.profile_name = "custom" if isinstance(rules, Profile) else str(rules)
        self.network = (network if isinstance(network, Network) or network is None
                        else load_network(os.fspath(network)))
        self.rules = select_rules(self.profile, string_list("select", select or []),
                                  string_list("ignore", ignore or []))
        self.channel = channel
        self.session = Session(self.profile, self.rules, self.network,
                               None if record is None else os.fspath(record), on_finding)
        # live findings the session withdrew are no findings (see live_findings())
        self.errors: list[str] = []
        self.error_count = 0
        self._outcome: Outcome | None = None

    # -- can.Listener ----------------------------------------------------------------------

    def on_message_received(self, msg: can.Message) -> None:
        if not isinstance(msg, can.Message):  # None or another object: no frame to check
            raise TypeError(f"msg: expected a can.Message, got {type(msg).__name__}")
        # queued for the session's checker thread: the Notifier's thread never waits for
        # the checks; under overload frames are dropped, counted, and reported (I004)
        self.session.submit(from_message(msg, self.channel))

    def on_error(self, exc: Exception) -> None:
        """A bus error in the Notifier's thread: kept (`errors`: the first ones,
        `error_count`: all), never lost. python-can's Notifier goes on reading after a
        handled error; a bus that is gone fails at once again, so repeats back off."""
        self.error_count += 1
        if len(self.errors) < MAX_ERRORS_KEPT:
            self.errors.append(f"{type(exc).__name__}: {exc}")
        elif self.error_count > MAX_ERRORS_KEPT:
            time.sleep(ERROR_BACKOFF_S)

    def stop(self) -> None:
        """End the session: the recording is closed and checked once more (idempotent)."""
        if self._outcome is None:
            self._outcome = self.session.close()

    def __enter__(self) -> Monitor:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    # -- results ---------------------------------------------------------------------------

    def result(self) -> InputResult | None:
        """`nmtcheck check` of the recording so far (final once stopped); None before the
        first frame."""
        if self._outcome is not None:
            return self._outcome.result
        return self.session.check()

    def findings(self, severity: str | None = None, rule: str | None = None) -> list[Finding]:
        """The findings so far: the offline check of the recording plus the live
        timeouts after its last frame. `severity` keeps that level and above
        (`"warning"`: warnings and errors); `rule` one code."""
        res = self.result()
        found = [*(res.findings if res else []), *self.session.extra_findings(res)]
        if severity is not None:
            if severity not in SEVERITIES:
                raise ValueError(f"severity must be one of {', '.join(SEVERITIES)}")
            keep = SEVERITIES[: SEVERITIES.index(severity) + 1]
            found = [f for f in found if f.severity in keep]
        if rule is not None:
            found = [f for f in found if f.rule == rule.upper()]
        return sorted(found, key=lambda f: (f.time, f.rule))

    def live_findings(self) -> list[LiveFinding]:
        """What the tracker reported as it happened (reconciled once `stop()` ran)."""
        self.session.drain()
        with self.session.lock:
            return list(self.session.live)

    def timeline(self) -> dict[tuple[str, int], list[Interval]]:
        """Each (channel, node)'s state intervals, as `nmtcheck timeline` has them."""
        res = self.result()
        return {} if res is None else {(m.channel, m.node): list(m.intervals)
                                       for m in res.nodes()}

    def nodes(self) -> list[NodeState]:
        """The live node table: state, last heartbeat, findings per node."""
        return self.session.nodes()

    def report(self, fmt: str = "text", path: str | os.PathLike[str] | None = None) -> str:
        """A report of the recording so far in any `nmtcheck check` format; written to
        `path` too when given."""
        res = self.result()
        options: dict[str, object] = {
            "fail_on": "error", "quiet": False, "max_findings": self.session.max_findings,
            "rules": {r.code: self.profile[r.code].severity for r in self.rules},
            "network_notes": list(self.network.notes) if self.network else [],
            "config": {"file": None, "profile": self.profile_name, "overrides": []}}
        text = renderer(fmt)([res] if res is not None else [], options)
        if path is not None:
            with open(path, "w", encoding="utf-8") as f:
                f.write(text)
        return text

    @property
    def dropped(self) -> int:
        """Frames received faster than the checks ran and dropped (counted, never silently:
        each report's I004 finding says how many)."""
        return self.session.dropped

    @property
    def recording(self) -> str:
        """The candump log of everything received (removed by `stop()` unless `record`)."""
        return self.session.path

"""A flood of failing boot processes (issue 22): past the per-rule cap the boot stage only
counts a P finding (no text, no process kept for it), and the check must report exactly
what it reports when the boot stage makes every finding and the engine alone caps them
(the per-process path): the same findings kept, the same count omitted, the same boot
report.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import pytest
from test_boot_flood import NETWORKS, _log, boot_nodes

from nmtcheck.engine import check_input, select_rules
from nmtcheck.processes import boot, boot_steps
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

REFUSED = "80171000" "02000106"  # abort 06010002h: attempt to write a read-only object
CONFIRMED = "60171000" "00000000"


def _flood(processes: int, nodes: tuple[int, ...] = (2, 3, 4, 5),
           channels: tuple[str, ...] = ("can0",), fail_every: int = 1) -> str:
    """CiA 302-2 boot processes, nodes (and channels) in turn, 100 us apart: boot-up,
    probe and answer, 1018h:01 upload and answer, a 1017h download (refused in every
    `fail_every`-th process), a start. No network file: the probe and the identity upload
    are the boot signature (SPEC_BOOT 8.2.4)."""
    out: list[str] = []
    t = 10.0
    for k in range(processes):
        n = nodes[k % len(nodes)]
        ch = channels[k // len(nodes) % len(channels)]
        answer = REFUSED if k % fail_every == 0 else CONFIRMED
        for cid, data in ((0x700 + n, "00"), (0x600 + n, "4000100000000000"),
                          (0x580 + n, "4300100092010200"), (0x600 + n, "4018100100000000"),
                          (0x580 + n, "4318100100030000"), (0x600 + n, "2B17100064000000"),
                          (0x580 + n, answer), (0x000, f"01{n:02X}")):
            out.append(f"({t:.6f}) {ch} {cid:03X}#{data}")
            t += 0.0001
    return "\n".join(out) + "\n"


def _run(tmp_path: Path, text: str, cap: int, network: str | None = None) -> InputResult:
    log = tmp_path / "flood.log"
    log.write_text(text)
    net = None
    if network is not None:
        (tmp_path / "net.toml").write_text(network)
        net = load_network(str(tmp_path / "net.toml"))
    prof = load_profile("default")
    return check_input(str(log), 0, prof, select_rules(prof, [], []), net, max_findings=cap)


def _per_process(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, text: str, cap: int,
                 network: str | None = None) -> InputResult:
    """The same check with the boot stage making every finding (no cap of its own)."""
    real = boot.run
    monkeypatch.setattr(boot, "run", lambda model, spool, net, profile, _cap=0:
                        real(model, spool, net, profile, 0))
    try:
        return _run(tmp_path, text, cap, network)
    finally:
        monkeypatch.setattr(boot, "run", real)


def _outcome(res: InputResult) -> Any:
    assert res.boot is not None
    return (boot_nodes(res), {k: c.as_dict() for k, c in res.boot.channels.items()},
            [(f.rule, f.channel, f.node, f.time, f.frame_index, f.line, f.message,
              f.boot_letter, f.evidence, f.causes) for f in res.findings],
            [(o.rule, o.count) for o in res.omitted])


def test_failing_flood_keeps_the_first_cap(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    text = _flood(200)
    res = _run(tmp_path, text, 50)
    p003 = [f for f in res.findings if f.rule == "P003"]
    assert len(p003) == 50
    assert [(o.rule, o.count) for o in res.omitted if o.rule.startswith("P")] == [("P003", 150)]
    # the first 50 in the rules' order: node 2's processes, then node 3's, ...
    assert [f.node for f in p003] == [2] * 50
    assert p003[0].boot_letter == "J" and "06010002h" in p003[0].message
    assert "started anyway" in p003[0].message
    # the boot stage made the 50 findings it hands on, and kept no process for the others
    assert res.boot is not None
    assert len(list(res.boot.for_rule("P003"))) == 50
    assert sum(res.boot.omitted.values()) == 150
    assert res.boot.nodes[("can0", 2)].processes == 50
    ref = _per_process(monkeypatch, tmp_path, text, 50)
    assert ref.boot is not None and len(list(ref.boot.for_rule("P003"))) == 200
    assert _outcome(res) == _outcome(ref)


@pytest.mark.parametrize("cap", [1, 49, 50, 51, 75, 120, 0])
@pytest.mark.parametrize("channels", [("can0",), ("can0", "can1")])
def test_cap_at_any_point_agrees_with_the_per_process_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cap: int,
        channels: tuple[str, ...]) -> None:
    # every third process fails: the cap falls inside a node, at its last (kept) process,
    # across nodes and across channels
    text = _flood(200, channels=channels, fail_every=3)
    res = _run(tmp_path, text, cap)
    made = [f for f in res.findings if f.rule == "P003"]
    left = sum(o.count for o in res.omitted if o.rule == "P003")
    assert len(made) + left == 67
    assert len(made) == (min(cap, 67) if cap else 67)
    assert _outcome(res) == _outcome(_per_process(monkeypatch, tmp_path, text, cap))


def _with_refusals(text: str, seed: int) -> str:
    """Half the 1017h confirmations of a log turned into refusals (abort 06010002h)."""
    rng = random.Random(seed)
    return "\n".join(ln.replace("#" + CONFIRMED, "#" + REFUSED) if rng.random() < 0.5 else ln
                     for ln in text.split("\n"))


@pytest.mark.parametrize("cap", [1, 10])
def test_mixed_failures_agree_with_the_per_process_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cap: int) -> None:
    """The random boot mixtures of test_boot_flood (P001 ... P008, mandatory nodes,
    keep-alive), half their configuration downloads refused, with a small cap: past it,
    the processes failed by a refusal alone are judged as columns, not evaluated."""
    evaluated = {"capped": 0, "all": 0}
    real = boot_steps.evaluate
    which = "capped"

    def counting(*args: Any) -> None:
        evaluated[which] += 1
        real(*args)

    monkeypatch.setattr(boot, "evaluate", counting)
    capped = 0
    for seed in range(6):
        text = _with_refusals(_log(seed, 0.5), seed)
        for network in NETWORKS.values():
            which = "capped"
            res = _run(tmp_path, text, cap, network)
            capped += sum(o.count for o in res.omitted if o.rule.startswith("P"))
            which = "all"
            ref = _per_process(monkeypatch, tmp_path, text, cap, network)
            assert _outcome(res) == _outcome(ref), (seed, network)
    # the cap was reached and processes were left to the columns, or this proves nothing
    assert capped > 0
    assert evaluated["capped"] < evaluated["all"], evaluated


def test_ok_flood_is_silent(tmp_path: Path) -> None:
    res = _run(tmp_path, _flood(200).replace(REFUSED, CONFIRMED), 50)
    assert not [f for f in res.findings if f.rule.startswith("P")]
    assert not [o for o in res.omitted if o.rule.startswith("P")]
    assert res.boot is not None and res.boot.omitted == {}
    assert res.boot.nodes[("can0", 2)].status == "ok"

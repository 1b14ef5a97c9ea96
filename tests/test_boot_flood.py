"""Boot-process floods (issue 22): the processes `boot.plainly_judged` judges at once, as
columns, come out exactly as the full per-process evaluation judges them.

Each log is a random mix of boot processes (boot-ups, resets, the manager's boot-up,
probes answered, refused, aborted or unanswered, identity uploads with right and wrong
values, configuration downloads, restores, software updates, heartbeats, RTRs, starts
early, late or never, long pauses), checked with and without the vectorised judgement;
everything the boot stage and the rules produce must be the same, and the vectorised
judgement must have judged a good share of the processes (or the test proves nothing).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from conftest import Checker

from nmtcheck.processes import boot, boot_steps
from nmtcheck.results import InputResult

NETWORKS = {
    "none": None,
    "ident": "master = 1\n[boot]\nmanager = true\n" + "".join(
        f"[nodes.{n}]\nvendor_id = 0x00000300\ndevice_type = 0x00020192\n" for n in (2, 3)),
    "consumer": "master = 1\n[boot]\nmanager = true\n" + "".join(
        f"[nodes.{n}]\nmanager_consumer_ms = 300\n" for n in (2, 3)),
    "keepalive": "master = 1\n[boot]\nmanager = true\nboot_time_ms = 2000\n"
                 "[nodes.2]\nassignment = 0x1D\n[nodes.3]\nassignment = 0x05\n",
}


Emit = Callable[..., None]


def _le(v: int) -> list[int]:
    return [v & 0xFF, v >> 8 & 0xFF, v >> 16 & 0xFF, v >> 24 & 0xFF]


def _anchor(rng: random.Random, f: Emit, n: int) -> None:
    r = rng.random()
    if r < 0.7:
        f(0x700 + n, [0])
    elif r < 0.8:
        f(0x000, [rng.choice([0x81, 0x82]), rng.choice([n, 0])])
    elif r < 0.85:
        f(0x701, [0])


def _uploads(rng: random.Random, f: Emit, n: int) -> None:
    for _k in range(rng.choice([0, 1, 1, 1, 2])):
        f(0x600 + n, [0x40, 0x00, 0x10, 0, 0, 0, 0, 0])
        a = rng.random()
        if a < 0.85:
            f(0x580 + n, [0x43, 0, 0x10, 0] + _le(rng.choice([0x00020192] * 5 + [0x20191])))
        elif a < 0.9:
            f(0x580 + n, [0x80, 0, 0x10, 0] + _le(0x06020000))
        elif a < 0.95:
            f(0x600 + n, [0x80, 0, 0x10, 0] + _le(0x05040000), dt=0.1)
    for sub in (1, 2):
        if rng.random() < 0.5:
            f(0x600 + n, [0x40, 0x18, 0x10, sub, 0, 0, 0, 0])
            if rng.random() < 0.9:
                v = 0x300 if sub == 1 else 0x4645
                f(0x580 + n, [0x43, 0x18, 0x10, sub] + _le(v if rng.random() < 0.9 else v + 1))


def _downloads(rng: random.Random, f: Emit, n: int) -> None:
    if rng.random() < 0.05:  # restore defaults, then the reset
        f(0x600 + n, [0x23, 0x11, 0x10, 1, 0x6C, 0x6F, 0x61, 0x64])
        f(0x580 + n, [0x60, 0x11, 0x10, 1, 0, 0, 0, 0])
        f(0x000, [0x81, n])
    if rng.random() < 0.05:  # a software update, unanswered
        f(0x600 + n, [0x2F, 0x51, 0x1F, 1, 1, 0, 0, 0])
    for _k in range(rng.choice([0, 1, 1, 2])):
        f(0x600 + n, [0x2B, 0x17, 0x10, 0, 0x64, 0, 0, 0])
        if rng.random() < 0.9:
            f(0x580 + n, [0x60, 0x17, 0x10, 0, 0, 0, 0, 0])


def _end(rng: random.Random, f: Emit, n: int, starts: float) -> None:
    if rng.random() < 0.5:
        f(0x700 + n, [rng.choice([0x7F, 0x7F, 0x05, 0x04])],
          dt=rng.choice([0.0, 0.001, 0.2, 0.299, 0.3, 0.4]))
    if rng.random() < 0.05:
        f(0x700 + n, None, dt=0.001)
    if rng.random() < starts:
        f(0x000, [0x01, rng.choice([n, n, n, 0])])
    if rng.random() < 0.3:
        f(0x700 + n, [0x05], dt=rng.choice([0.001, 0.2]))


def _log(seed: int, starts: float) -> str:
    rng = random.Random(seed)
    t = 10.0
    out: list[str] = []

    def f(cid: int, data: list[int] | None, dt: float | None = None) -> None:
        nonlocal t
        t += dt if dt is not None else rng.choice([0.0001, 0.0005, 0.001, 0.003])
        t = round(t, rng.choice([6, 3]))  # ties, as in logs with 1 ms timestamps
        body = "R" if data is None else "".join(f"{b:02X}" for b in data)
        out.append(f"({t:.6f}) can0 {cid:03X}#{body}")

    f(0x701, [0])
    for _ in range(rng.choice([5, 40, 120])):
        n = rng.choice([2, 3])
        _anchor(rng, f, n)
        _uploads(rng, f, n)
        _downloads(rng, f, n)
        _end(rng, f, n, starts)
        if rng.random() < 0.03:
            t += rng.choice([1.5, 12.0])
    f(0x080, [], dt=rng.choice([0.001, 2.5, 12.0]))
    return "\n".join(out) + "\n"


def boot_nodes(res: InputResult) -> dict[Any, Any]:
    """Every node's boot report and every column of its process spans, comparable."""
    assert res.boot is not None
    nodes = {}
    for key, rep in res.boot.nodes.items():
        sp = rep.spans
        nodes[key] = (rep.as_dict(), rep.candidates, rep.processes, sp.start.tolist(),
                      sp.end.tolist(), sp.status.tolist(), sp.letter.tolist(),
                      [sp.last_step[k] for k in sp.step.tolist()], np.nan_to_num(sp.ev_time,
                      nan=-1.0).tolist(), sp.ev_idx.tolist(), sp.ev_line.tolist())
    return nodes


def _outcome(checker: Checker, log: str, network: str | None) -> Any:
    res = checker.run(log, network=network)
    assert res.boot is not None
    return (boot_nodes(res), {k: c.as_dict() for k, c in res.boot.channels.items()},
            [(f.code, f.node, f.time, f.frame_index, f.line, f.message, f.letter, f.evidence)
             for f in res.boot.findings],
            [(f.rule, f.node, f.time, f.frame_index, f.message, f.boot_letter, f.evidence)
             for f in res.findings])


@pytest.mark.parametrize("starts", [0.85, 0.2])
def test_vectorised_judgement_agrees_with_full_evaluation(
        checker: Checker, monkeypatch: pytest.MonkeyPatch, starts: float) -> None:
    judged = {"ok": 0, "incomplete": 0, "processes": 0}
    real = boot_steps.plainly_judged

    def counting(*args: Any) -> boot_steps.Plain:
        found = real(*args)
        judged["ok"] += int(found.ok.sum())
        judged["incomplete"] += int(found.incomplete.sum())
        judged["processes"] += len(found.ok)
        return found

    def nothing(nd: Any, c: boot_steps.Procs, *args: Any) -> boot_steps.Plain:
        n = len(c)
        return boot_steps.Plain(np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, np.int16),
                           np.full(n, np.nan), np.full(n, -1, np.int64), np.zeros(n, np.int64))

    for seed in range(12):
        log = _log(seed, starts)
        for network in NETWORKS.values():
            monkeypatch.setattr(boot, "plainly_judged", counting)
            fast = _outcome(checker, log, network)
            monkeypatch.setattr(boot, "plainly_judged", nothing)
            assert _outcome(checker, log, network) == fast, (seed, network)
    # the comparison is worth something only if the columns judged many processes
    if starts > 0.5:
        assert judged["ok"] > judged["processes"] // 10, judged
    else:
        assert judged["ok"] > 20 and judged["incomplete"] > 50, judged

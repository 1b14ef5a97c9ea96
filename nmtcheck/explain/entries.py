"""The entries of a finding's `causes` and `reactions` (SPEC §8.6.3, §9.3): how one is
written, when an effect began (t_e), and which entries are causes and which reactions.
Offline (`causes.py`, `chains.py`) and live (`nmtcheck/live/causes.py`) alike."""

from __future__ import annotations

from typing import Any

from nmtcheck.protocol.nmt import EPS

KINDS = ("reboot", "emcy", "emcy_other", "error_frames", "frames_lost", "silence", "nmt",
         "sdo_write", "bootup_cluster", "boot_process", "finding", "node_state", "node_silent",
         "bootup", "guarding_gap", "pdo_gap", "sync_gap", "lss_bit_timing")


# The role of a reaction after the finding's time by its kind (§9.3.3): a frame of the
# finding's node reports what happened to it; another node's frame or a command responds
# to it; the rest is the bus.
REPORT_KINDS = ("reboot", "emcy", "node_state")
BUS_KINDS = ("error_frames", "frames_lost", "silence")


def effect_start(rule: str, a0: float, tf: float, period: float | None) -> float:
    """t_e of §9.3.2: when the finding's effect began. H001: when the first missed
    heartbeat was due (a0 + the period at a0), at most t_f; G002, B001 (a), S004: the
    unanswered request, the reset, the command (a0); B002 and the rest: t_f."""
    if rule == "H001":
        return min(a0 + period, tf) if period else tf
    if rule in ("G002", "B001", "S004"):
        return min(a0, tf)
    return tf


def split(entries: list[dict[str, Any]], te: float, tf: float, node: int | None
          ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Causes (their time at or before t_e) and reactions (after it), each reaction with
    its `role` (§9.3.3). An entry that began at or before t_e and lasts beyond it is a
    cause; a frame that reports an earlier condition keeps its own time. A logger's drop
    is positioned at the first frame after the loss, so one up to t_f may have hidden the
    frame whose absence is the finding: a cause, as §9.3.4's `frames_lost` link has it."""
    causes: list[dict[str, Any]] = []
    reactions: list[dict[str, Any]] = []
    for c in entries:
        hides = c["kind"] == "frames_lost" and c["time"] <= tf + EPS
        if (c["time"] <= te + EPS or hides) and c["kind"] != "reboot":
            causes.append(c)
            continue
        if c["time"] <= tf + EPS:
            role = "during"
        elif c["kind"] in REPORT_KINDS and (c.get("node") is None or c["node"] == node):
            role = "report"
        elif c["kind"] in BUS_KINDS:
            role = "bus"
        else:
            role = "response"
        reactions.append({**c, "role": role})
    return causes, reactions


def capped(found: list[dict[str, Any]], cap: int) -> tuple[list[dict[str, Any]], int]:
    """Sorted by time (ties by kind); past `cap`, the lowest kinds are kept."""
    rank = {k: i for i, k in enumerate(KINDS)}
    if len(found) > cap:
        keep = sorted(found, key=lambda c: (rank[c["kind"]], c["time"]))[:cap]
        omitted = len(found) - cap
    else:
        keep, omitted = found, 0
    keep.sort(key=lambda c: (c["time"], rank[c["kind"]]))
    return keep, omitted


def cause_entry(kind: str, time: float, idx: int | None, line: int | None, text: str,
                node: int | None = None, end: float | None = None, count: int | None = None,
                code: str | None = None, link: str = "window") -> dict[str, Any]:
    """One entry of a finding's `causes` (SPEC §8.6, §9.3.6), offline and live alike:
    `link` is "window" for an event found in the finding's window (§8.6.3), else the
    name of the chain link (§9.3.4) whose test it passed."""
    return {"kind": kind, "time": round(float(time), 6),
            "end": None if end is None else round(float(end), 6),
            "frame_index": idx, "line": line or None, "node": node, "count": count,
            "code": code, "text": text, "link": link, "depth": 1, "parent": None,
            "basis": None, "alternatives": 0}


def cluster_entry(hits: list[tuple[float, int, int, int]], own: tuple[float, int, int, int],
                  nodes: str, cluster: float) -> dict[str, Any]:
    """A `bootup_cluster` entry (§9.3.3): its time the earliest and its end the latest
    boot-up among N (`own`) and the other nodes it lists, so that it stands for a common
    cause before the first of them; it points at the earliest one's frame."""
    every = sorted([*hits, own])
    first = every[0]
    return cause_entry("bootup_cluster", first[0], first[2] if first[2] >= 0 else None,
                       first[3] or None,
                       f"boot-ups of node(s) {nodes} within {cluster * 1000:g} ms: "
                       "several nodes rebooted together", None, end=every[-1][0])

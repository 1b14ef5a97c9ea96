"""What `nmtcheck timeline` and the HTML timeline draw of SYNC, PDO and EMCY (SPEC §9.4.2):
each channel's SYNC line, each Y001/D001/D004 finding's gap as an interval, each node's
EMCYs with their meaning and CANopenNode's detail, and the SYNC ticks aggregated so that a
page stays small whatever the length of the log."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.protocol import emcy
from nmtcheck.reporters import comm_report
from nmtcheck.results import Finding, InputResult

GAP_RULES = {"Y001": "sync_gap", "D001": "pdo_gap", "D004": "pdo_gap"}
# The HTML page carries at most this many SYNC times per channel, and MAX_SYNC_TICKS_PAGE
# in all (each channel with SYNC at least MIN_SYNC_TICKS); a channel with more gets its
# SYNC frames counted in as many equal bins instead (a tick per bin with frames).
MAX_SYNC_TICKS = 20_000
MAX_SYNC_TICKS_PAGE = 200_000
MIN_SYNC_TICKS = 1000
# EMCY markers a page draws, shared among the nodes that sent EMCYs (each gets at least
# MIN_EMCY_MARKS_PER_NODE); the markers' texts are kept once per distinct text.
MAX_EMCY_MARKS = 20_000
MIN_EMCY_MARKS_PER_NODE = 200
EMCY_CLASSES = ("communication", "reset", "other")


@dataclass(frozen=True)
class GapInterval:
    """A Y001, D001 or D004 finding's gap: from the last frame before it to the next one
    (`open`: none came, the gap runs to the channel's end)."""

    kind: str  # sync_gap | pdo_gap
    finding: Finding
    cob_id: str | None
    start: float
    end: float
    open: bool


def finding_gaps(res: InputResult) -> list[GapInterval]:
    """Every Y001, D001 and D004 finding's gap, in the findings' order."""
    out = []
    for f in res.findings:
        kind = GAP_RULES.get(f.rule)
        if kind is None or f.channel is None:
            continue
        span = (_sync_gap(res, f) if f.rule == "Y001" else _pdo_gap(res, f))
        if span is None:
            continue
        last, nxt = span
        end = res.model.end_of(f.channel)
        out.append(GapInterval(kind, f, comm_report.finding_cob_id(res, f), last,
                               nxt if np.isfinite(nxt) else max(end, last),
                               not np.isfinite(nxt)))
    return out


def _sync_gap(res: InputResult, f: Finding) -> tuple[float, float] | None:
    analysis = sync_stage.of(res.model)
    gap = analysis.gaps.get((str(f.channel), round(f.time, 9))) if analysis else None
    return None if gap is None else (gap.last_ts, gap.next_ts)


def _pdo_gap(res: InputResult, f: Finding) -> tuple[float, float] | None:
    """D004's gap as the rule kept it; D001's from its stream: the last TPDO at or before
    the finding's time (when the limit ran out) and the first after it."""
    analysis = pdo_stage.of(res.model)
    if analysis is None:
        return None
    if f.rule == "D004":
        gap = analysis.gaps.get((str(f.channel), int(f.node or 0), round(f.time, 9)))
        return None if gap is None else (gap.last_ts, gap.next_ts)
    cob = comm_report.finding_cob_id(res, f)
    st = next((s for s in analysis.streams if s.channel == f.channel
               and f"{s.cob_id:03X}h" == cob), None)
    if st is None:
        return None
    ts = st.frames()[0]
    k = int(np.searchsorted(ts, f.time, side="right"))
    if k == 0:
        return None
    return float(ts[k - 1]), float(ts[k]) if k < len(ts) else float("inf")


def sync_summary(res: InputResult, channel: str, y001_checked: bool = True) -> str | None:
    """The channel's SYNC line of `nmtcheck timeline`: COB-ID, producer, period, frames and
    the gaps over the timeout (Y001's findings, `y001_checked` when the rule ran); None for
    a channel without SYNC."""
    analysis = sync_stage.of(res.model)
    sc = analysis.channels.get(channel) if analysis is not None else None
    if sc is None:
        return None
    producer = (f"node {sc.producer.value} ({sc.producer.source})"
                if sc.producer.known and sc.producer.value else "unknown")
    period = (f"{sc.period.value} us ({sc.period.source})" if sc.period.known
              else "unknown")
    iv = sc.intervals()
    # a log without timestamps has frame numbers for times: no interval to measure
    measured = (f", median interval {float(np.median(iv)) * 1e6:.1f} us"
                if len(iv) and not res.stats.order_only else "")
    if not y001_checked:
        gaps = "gaps over the timeout: Y001 not checked (the profile turns it off)"
    elif "Y001" in res.not_evaluated:
        gaps = "gaps over the timeout: Y001 not evaluated"
    else:
        n = sum(1 for f in res.findings if f.rule == "Y001" and f.channel == channel)
        gaps = f"{n} gap{'' if n == 1 else 's'} over the timeout (Y001)"
    return (f"SYNC {sc.cob_id:03X}h ({sc.cob_id_source}): producer {producer}, period "
            f"{period}{measured}, {len(sc)} frames, {gaps}")


def sync_ticks_per_channel(results: list[InputResult]) -> int:
    """How many SYNC times (or bins) each channel with SYNC may have on the page."""
    channels = 0
    for res in results:
        analysis = sync_stage.of(res.model)
        channels += 0 if analysis is None else len(analysis.channels)
    return max(min(MAX_SYNC_TICKS, MAX_SYNC_TICKS_PAGE // max(channels, 1)), MIN_SYNC_TICKS)


def sync_ticks(res: InputResult, channel: str, begin: float, limit: int = MAX_SYNC_TICKS
               ) -> dict[str, Any] | None:
    """The SYNC frames of a channel for the HTML row, seconds from `begin`: their times when
    there are at most `limit`, else `bins` (the frames counted in `limit` equal bins of
    `width` seconds from `t0`); None for a channel without SYNC."""
    analysis = sync_stage.of(res.model)
    sc = analysis.channels.get(channel) if analysis is not None else None
    if sc is None:
        return None
    ts = sc.ts[~sc.rtr] if len(sc.rtr) else sc.ts
    out: dict[str, Any] = {"cob_id": f"{sc.cob_id:03X}h", "frames": len(sc),
                           "title": sync_summary(res, channel), "ticks": None, "bins": None}
    if len(ts) <= limit:
        out["ticks"] = np.round(ts - begin, 6).tolist()
        return out
    t0, t1 = float(ts[0]), float(ts[-1])
    width = max((t1 - t0) / limit, 1e-6)
    counts = np.bincount(np.minimum(((ts - t0) / width).astype(np.int64), limit - 1),
                         minlength=limit)
    out["bins"] = {"t0": round(t0 - begin, 6), "width": width, "counts": counts.tolist()}
    return out


def emcy_class(code: int | None) -> str:
    """The colour class of an EMCY on the timeline: 81xxh and 82xxh are communication
    errors, a code below 0100h an error reset, the rest (malformed included) other."""
    if code is None:
        return "other"
    if code >> 8 in (0x81, 0x82):
        return "communication"
    return "reset" if code < 0x100 else "other"


@dataclass(frozen=True)
class EmcyRow:
    """One EMCY of a node: its decoded text and CANopenNode's detail when recognised."""

    channel: str
    node: int
    time: float
    frame_index: int
    line: int
    code: int | None
    register: int | None
    text: str
    canopennode: dict[str, object] | None

    @property
    def detail(self) -> str:
        """`CANopenNode: SYNC timeout (us since the last SYNC = 30291), error bit 18h`."""
        cn = self.canopennode
        return "" if cn is None else f"CANopenNode: {cn['meaning']}, error bit {cn['error_bit']}"


def emcy_rows(res: InputResult, channel: str, node: int, limit: int | None = None
              ) -> Iterator[EmcyRow]:
    """A node's EMCYs in file order (the first `limit` of them)."""
    analysis = emcy_stage.of(res.model)
    e = analysis.nodes.get((channel, node)) if analysis is not None else None
    if e is None:
        return
    n = len(e) if limit is None else min(len(e), limit)
    for k in range(n):
        data, dlc = e.data_bytes(k), int(e.dlc[k])
        code, text = emcy.describe(data, dlc)
        yield EmcyRow(channel, node, float(e.ts[k]), int(e.idx[k]), int(e.line[k]), code,
                      data[2] if dlc >= 3 else None, text, emcy.canopennode_detail(data, dlc))


def emcy_count(res: InputResult, channel: str, node: int) -> int:
    analysis = emcy_stage.of(res.model)
    e = analysis.nodes.get((channel, node)) if analysis is not None else None
    return 0 if e is None else len(e)


def emcy_marks_per_node(results: list[InputResult]) -> int:
    """How many EMCY markers each node may have on the page."""
    senders = sum(1 for res in results for m in res.nodes()
                  if emcy_count(res, m.channel, m.node))
    return max(MAX_EMCY_MARKS // max(senders, 1), MIN_EMCY_MARKS_PER_NODE)


def sync_lane(res: InputResult, channel: str, begin: float, gaps: list[GapInterval],
              group_of: dict[int, tuple[str, int]], limit: int = MAX_SYNC_TICKS
              ) -> dict[str, Any] | None:
    """The HTML SYNC row of a channel (times from `begin`): the ticks of `sync_ticks` and
    Y001's gaps as `[start, end, finding group, occurrence, open]`, in red on the page."""
    lane = sync_ticks(res, channel, begin, limit)
    if lane is None:
        return None
    lane["gaps"] = [[round(g.start - begin, 6), round(g.end - begin, 6),
                     *group_of.get(id(g.finding), (None, None)), g.open]
                    for g in gaps if g.kind == "sync_gap" and g.finding.channel == channel]
    return lane


def emcy_marks(res: InputResult, channel: str, node: int, begin: float, limit: int,
               texts: dict[str, int]) -> tuple[list[list[Any]], int]:
    """A node's EMCY markers, `[time from begin, class, text, line]` with the text as an
    index into `texts` (added there when new), and how many EMCYs are left out past
    `limit`."""
    marks = []
    for e in emcy_rows(res, channel, node, limit):
        text = e.text + (f"\n{e.detail}" if e.canopennode is not None else "")
        marks.append([round(e.time - begin, 6), EMCY_CLASSES.index(emcy_class(e.code)),
                      texts.setdefault(text, len(texts)), e.line or None])
    return marks, emcy_count(res, channel, node) - len(marks)

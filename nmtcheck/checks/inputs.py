"""Input rules (I): problems of the log itself, not of the network.

They judge what the reader counted (`model.stats`, an `InputStats`) and how many
frames CANopen decoding saw. Their findings have channel and node None: one per
input and rule, exempt from the UNKNOWN rule (SPEC §3). Time and frame are those
of the first record concerned.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from nmtcheck.checks.base import Param, Problem, input_rule
from nmtcheck.errors import InputError
from nmtcheck.readers import TEXT_FORMATS, InputStats
from nmtcheck.timeline.model import InputModel

LINES_SHOWN = 5


def _first_frame(model: InputModel) -> tuple[float, int | None, int | None]:
    """(time, frame index, line) of the input's first frame, or (0.0, None, None)."""
    stats = model.stats
    if not stats.frames:
        return 0.0, None, None
    start = float(stats.start or 0.0)
    hit = model.decoded.first_frame_at_or_after([start])[0]
    return (start, *hit) if hit is not None else (start, 0, None)


def _last_frame(model: InputModel) -> tuple[float, int | None, int | None]:
    """(time, frame index, line) of the input's last frame, or (0.0, None, None)."""
    stats = model.stats
    if not stats.frames:
        return 0.0, None, None
    end = float(stats.end or 0.0)
    last = model.decoded.last_frame(end)
    if last is None:
        return end, stats.frames - 1, None
    ts, at = last
    return ts, at.idx, at.line


def _frame_after_line(model: InputModel, line: int) -> tuple[float, int | None]:
    """(time, index) of the first frame after record `line`: where a skipped record sits in
    time; the last frame if none follows, (0.0, None) without frames."""
    return model.decoded.first_frame_after_line(line) or (0.0, None)


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


@input_rule("I001", "nothing-to-check", "error", exempt_from_unknown=True, scope="input")
def nothing_to_check(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The input holds no 11-bit CAN frame: nothing was checked.

    **What it checks.** The input's format is known (detected, or given with
    `--input-format`) but it holds no 11-bit data or remote frame: only extended
    or error frames, only records that are no frames, or every record was skipped
    as unparseable. One finding per input, at its first record. The message says
    what the input held instead: how many of its records (lines, for text formats)
    were frames (extended, error), skipped (the first one's line and why), notes or
    comments, other non-frame records. An empty file is not this rule: it stays an
    input error (exit 2).

    **Why it matters.** A CI gate must not take "no finding" for a pass when no
    CANopen frame was looked at: a log of another protocol, the wrong
    `--input-format`, or a log the reader could not understand all look clean
    otherwise.

    **Example.** `nmtcheck check candump.log --input-format trc`: every line is a
    skipped record, 0 frames are checked.
    """
    stats = model.stats
    if stats is None or model.decoded.standard_frames:
        return
    ts, idx, line = _first_frame(model)
    if idx is None and stats.skipped_lines and stats.format in TEXT_FORMATS:
        line = stats.skipped_lines[0]
    yield Problem(None, None, ts, f"no 11-bit CAN data or remote frame to check in this "
                  f"{stats.format} input: {_what_was_read(stats)}", idx, line)


def _what_was_read(stats: InputStats) -> str:
    """Why nothing was checked: which kinds of records (lines, for text formats) the input
    held, e.g. `12 lines: no frame, 10 skipped (first at line 3: <why>), 2 notes or
    comments` — never only a guess at the format (SPEC §1)."""
    text = stats.format in TEXT_FORMATS
    unit = "line" if text else "record"
    total = stats.frames + stats.skipped + stats.ignored
    if stats.frames:
        kinds = [f"{stats.extended} extended"] if stats.extended else []
        if stats.error_frames:
            kinds.append(_plural(stats.error_frames, "error frame"))
        parts = [_plural(stats.frames, "frame") + (f" ({', '.join(kinds)})" if kinds else "")]
    else:
        parts = ["no frame"]
    if stats.skipped:
        numbers = [n for n in stats.skipped_lines if n > 0]
        where = [f"first at {unit} {numbers[0]}"] if numbers else []
        first = ", ".join(where) + (": " if where and stats.skip_reason else "") + (
            stats.skip_reason or "")
        parts.append(f"{stats.skipped} skipped" + (f" ({first})" if first else ""))
    if stats.notes:
        parts.append(f"{stats.notes} "
                     + ("note or comment" if stats.notes == 1 else "notes or comments"))
    if stats.ignored > stats.notes:
        parts.append(_plural(stats.ignored - stats.notes, "other non-frame record"))
    out = f"{_plural(total, unit)}: {', '.join(parts)}"
    if stats.skipped and stats.skipped == total:
        out += (f"; not one is a {stats.format} record: if the log is of another format, "
                "name it with --input-format")
    return out


@input_rule("I002", "truncated-input", "warning", exempt_from_unknown=True, scope="input")
def truncated_input(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The input ends early: inside a record, a compressed stream or a container.

    **What it checks.** The reader met the end of the input inside a record (a
    BLF object, an MCAP record), a compressed stream (`.gz`, `.bz2`, `.xz`,
    `.zst`) or a container, and read it up to there. A text log's last line
    without a newline whose frame has fewer data bytes than a CANopen frame of its
    CAN-ID (`000#01`, `703#`) was cut there too: it is a skipped record, not a
    malformed frame. One finding per input, at the last record read. `--strict`
    makes this an input error (exit 2).

    **Why it matters.** A log cut off while recording or copying is checked only
    up to the cut: verdicts near the end (a timeout still running, a boot-up
    never seen) may be missing, and the recording is not what was on the bus.

    **Example.** A `.log.gz` copied while the logger was still writing it.
    """
    stats = model.stats
    if stats is None or not stats.truncated:
        return
    ts, idx, line = _last_frame(model)
    where = (f"after {_plural(stats.frames, 'frame')}" if stats.frames
             else "before its first frame")
    yield Problem(None, None, ts, f"the input ends early (cut off or damaged) {where}: "
                  "it was read up to there, verdicts near the end may be missing", idx, line)


@input_rule("I003", "skipped-records", "warning",
      Param("max_skipped", int, "how many unparseable records are tolerated", 0),
      Param("unreadable_share", float, "past this share of an input's records skipped "
            "(frames and skipped records), the input was not read: an input error (exit 2), "
            "not a finding; 1 never", 0.5, maximum=1.0),
      exempt_from_unknown=True, scope="input")
def skipped_records(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """Records of the input could not be parsed.

    **What it checks.** More than `max_skipped` records could not be parsed; the
    message gives their count and the first line numbers (for binary formats, the
    record numbers where known). Records that a format defines and that are no
    frames (ASC status and statistics lines, `TxRq`, comments inside the log) are
    not skipped records. One finding per input, at the frame after the first
    skipped record. `--strict` makes the first one an input error (exit 2).

    **Why it matters.** A frame hidden in an unparseable line is a frame the rules
    never saw: a heartbeat gap or a missing boot-up may be the reader's, not the
    network's. A log edited by hand or damaged in transfer shows up here.

    When more than `unreadable_share` of the input's records (frames and skipped
    records; half by default) were skipped, the input was not read: it is an
    unreadable input (exit 2, named in every report), not a finding, so a log whose
    lines turned into something else after its first few never passes the gate.

    **Example.** A candump log with a line `garbage here` between two frames.
    """
    stats = model.stats
    if stats is None or stats.skipped <= int(p.get("max_skipped", 0)):
        return
    text = stats.format in TEXT_FORMATS
    numbers = [n for n in stats.skipped_lines if n > 0]
    where = ""
    if numbers:
        shown = ", ".join(map(str, numbers[:LINES_SHOWN]))
        more = ", …" if stats.skipped > min(len(numbers), LINES_SHOWN) else ""
        where = (f" (first at line{'s' if len(numbers) > 1 else ''} {shown}{more})" if text
                 else f" (first at record{'s' if len(numbers) > 1 else ''} {shown}{more})")
    ts, idx = (_frame_after_line(model, numbers[0]) if numbers and text
               else _first_frame(model)[:2])
    line = numbers[0] if numbers and text else None
    yield Problem(None, None, ts, f"{_plural(stats.skipped, 'record')} could not be parsed as "
                  f"{stats.format}{where}", idx, line)


def refuse_mostly_unread(stats: InputStats, standard_frames: int, p: dict[str, Any]
                         ) -> None:
    """An input error when more than `unreadable_share` of the input's records (frames and
    skipped records) were skipped: a log whose lines turned into something else after its
    first few (`cat -n` from line 21) would pass with most of it unseen. Nothing when the
    share is at most that, or when no 11-bit frame was read (I001, an error, says so)."""
    total = stats.frames + stats.skipped
    share = float(p.get("unreadable_share", 0.5))
    if not standard_frames or not stats.skipped or stats.skipped <= share * total:
        return
    numbers = [n for n in stats.skipped_lines if n > 0]
    unit = "line" if stats.format in TEXT_FORMATS else "record"
    first = f"first at {unit} {numbers[0]}" if numbers else ""
    why = ", ".join(x for x in (first, stats.skip_reason) if x)
    raise InputError(stats.path, f"{stats.skipped} of {total} records could not be parsed as "
                     f"{stats.format}" + (f" ({why})" if why else "") + f": more than "
                     f"{share:.0%} of the input is no {stats.format} record, so it was not "
                     "read (I003 unreadable_share; if the log is of another format, name it "
                     "with --input-format)")


@input_rule("I004", "frames-lost", "warning", exempt_from_unknown=True, scope="input")
def frames_lost(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The logger reported frames it dropped.

    **What it checks.** The log says that the logger lost frames: candump
    `DROPCOUNT`, BLF data-lost events, CANedge/CL2000 `Lost` counts. One finding
    per input with the total count, at the first loss: where the logger's record
    says it happened (BLF, CL2000), else at the first frame after the record
    (`DROPCOUNT`); at the input's first frame where no record places it (frames a
    live monitor could not keep up with).

    **Why it matters.** A heartbeat gap, a missing boot-up or an unanswered
    guarding request in that window may be the logger's loss, not the network's:
    judge timing findings of such a log with care, or record again with a larger
    receive buffer.

    **Example.** `DROPCOUNT: 12` in a candump log.
    """
    stats = model.stats
    if stats is None or not stats.dropped:
        return
    lost = _plural(stats.dropped, "frame")
    placed = model.decoded.drop_moments(stats.drops)
    if not len(placed["ts"]):
        ts, idx, line = _first_frame(model)
        yield Problem(None, None, ts, f"the logger reported {lost} lost (the moment of the "
                      "first loss is not recorded: the finding is at the first frame); "
                      "timing findings may be the logger's", idx, line)
        return
    first = int(np.lexsort((placed["idx"], placed["ts"]))[0])
    ts, idx, line = (float(placed["ts"][first]), int(placed["idx"][first]),
                     int(placed["line"][first]))
    records = _plural(len(stats.drops), f"{stats.drop_record} record")
    where = f" (the record at line {line})" if line and stats.format in TEXT_FORMATS else ""
    yield Problem(None, None, ts, f"the logger reported {lost} lost in {records}, the first "
                  f"before frame {idx}{where}; timing findings around it may be the "
                  "logger's", idx, line or None)


@input_rule("I005", "timestamps-backwards", "warning", exempt_from_unknown=True, scope="input")
def timestamps_backwards(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """Timestamps go backwards between consecutive records.

    **What it checks.** A frame's timestamp is earlier than the one before it in
    the file. Frames are kept in file order; the message gives the count and the
    first place. One finding per input, at the first frame that goes back.

    Where a channel's time goes back by more than a second, to the start of the
    recording or before it, and stays back, or by any amount to frames the input
    already had (a log pasted in overlapping pieces), or after a note that frames
    were left out between two frames (`[... snip ...]`, `...`: an edit made on
    purpose, which the input summary names and which is no finding), a new
    recording begins: from there on the
    frames are a capture of their own, checked as a trace of its own, and a channel
    an earlier capture had is named `NAME (capture K)` there (the network file's
    configuration for NAME applies to it). Where it goes back by more than 50 ms
    within the recording and stays back, the logger's clock stepped back (NTP): the
    frames after it are timed as if it had not, continuing from the latest frame
    before it. The message names each capture's start and each clock step.

    **Why it matters.** Merged or re-ordered logs make every timing rule
    unreliable: gaps, early heartbeats and command windows are measured between
    frames that were not neighbours on the bus. Two recordings joined in one file
    are two traces: checked as one, every node of the first would fall silent "for
    the rest of the trace" and the second's PDOs be judged against the first's
    states.

    **Example.** `cat run1.asc run2.asc` (both count from 0 s), or two candump
    logs of one session joined in the wrong order.
    """
    stats = model.stats
    # captures after notes of left-out frames only are the user's own edit, no finding:
    # the text report's input summary says so (InputStats.left_out_text)
    if stats is None or not stats.backwards_timestamps:
        return
    first = stats.first_backwards
    if first is None:
        ts, idx, line = _first_frame(model)
    else:
        idx, line, ts = first
    where = f" (first at line {line})" if line and stats.format in TEXT_FORMATS else (
        f" (first at frame {idx})" if idx is not None else "")
    said = f"timestamps go backwards {_plural(stats.backwards_timestamps, 'time')}{where}"
    after_notes = {first for _note, first in stats.left_out_restarts}
    back = [r for r in stats.restarts if r[1] not in after_notes]
    explained = len(stats.restarts) + len(stats.clock_steps)  # each may explain one step
    if not explained:
        said += ": frames are kept in file order, timing findings may be unreliable"
    if (left_out := stats.left_out_text()) is not None:
        said += ": " + left_out
    if back:  # new recordings in the input (nmtcheck/readers/captures.py)
        at = ", ".join(_place(stats, i, ln) for i, ln, _t in back[:3])
        said += (f": time starts again at {at}{', …' if len(back) > 3 else ''}, "
                 f"{len(stats.restarts) + 1} captures, each checked as a trace of its own "
                 "(a later capture's channels are named 'NAME (capture K)')")
    if stats.clock_steps:  # the logger's clock stepped back within a recording
        at = ", ".join(f"{step:.3f} s at {_place(stats, i, ln)}"
                       for i, ln, step in stats.clock_steps[:3])
        said += (f"{';' if stats.restarts else ':'} the logger's clock stepped back {at}"
                 f"{', …' if len(stats.clock_steps) > 3 else ''}: the frames after a step "
                 "are timed as if it had not, that much later than their stamps")
    if explained and stats.backwards_timestamps > explained:
        said += "; the smaller steps back may make timing findings unreliable"
    yield Problem(None, None, ts, said, idx, line or None)


def _place(stats: InputStats, idx: int, line: int) -> str:
    """`line L` in a text log, `frame F` in a binary one."""
    return f"line {line}" if line and stats.format in TEXT_FORMATS else f"frame {idx}"


@input_rule("I006", "no-timestamps", "warning", exempt_from_unknown=True, scope="input")
def no_timestamps(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The input has no usable timestamps: only the order of its frames was checked.

    **What it checks.** The log has no timestamps written (`candump can0` screen
    output without `-t`, bare `ID#DATA` lines pasted from a terminal) or every
    timestamp is equal. Frames are kept in file order and the timeline is ordered
    by frame index (its times are frame numbers). Rules that need only order (B001's
    sign of life before the boot-up, B002, B003, G001, S001, S002, S003, S005, C,
    N001, N002's state pattern) are evaluated; rules that need time (H001-H004,
    G002, G003, S004, B001's timeout and late start, N002's intervals, the grace and
    stale-report windows) are not. One finding per input, at its first frame.

    **Why it matters.** Without time, a silent node and a healthy one look the
    same: a gate that passed such a log has not checked any timing. Record with
    `candump -L` or `candump -ta`.

    **Example.** `candump can0 > log.txt` pasted into an issue.
    """
    stats = model.stats
    if stats is None or not stats.order_only:
        return
    why = "none written" if not stats.timestamped else "every timestamp is equal"
    ts, idx, line = _first_frame(model)
    yield Problem(None, None, ts, f"no timestamps ({why}): frames checked in file order "
                  "only; heartbeat, guarding and other timing rules were not evaluated "
                  "(record with candump -L or -ta)", idx, line or None)


@input_rule("I007", "recording-gap", "warning", exempt_from_unknown=True, scope="network")
def recording_gap(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """No frame at all on a channel for longer than every heartbeat and guarding limit
    running there, then its producers resume: the recorder's gap, or the network's.

    **What it checks.** No frame of any kind is recorded (on any channel of the input)
    for longer than every H001 timeout and G002 response timeout running on the channel
    at its start (at least one running), and frames follow it. A log cannot tell a
    recorder that was off (a clock step forward, two recordings joined with `cat`, a
    logger that paused) from a network that was off. H001, G002, G003 and B001's
    boot-up timeout do not count the time inside the gap: their limits count again from
    its end, so a node that stays silent after it is judged from there. A single node
    falling silent while others send is H001, never I007. One finding per gap and
    channel, at the gap's end (the frame that resumes it), naming its span and the nodes
    whose limits ran out inside it.

    **Why it matters.** Judged as a network, every producer would time out at once and
    fail a gate on what may be the recorder's doing; not judged at all, a network that
    was off would pass. The warning says which it cannot tell.

    **Example.** A candump log whose clock steps forward by 100 s in the middle: every
    node's heartbeat "stops" for 100 s, then all go on in phase.
    """
    for cm in model.channels:
        for gap in cm.recording_gaps:
            names = ", ".join(str(n) for n in gap.nodes)
            who = (f"node {names} is" if len(gap.nodes) == 1 else
                   f"nodes {names} are" if gap.nodes else "no node is")
            yield Problem(cm.name, None, gap.end,
                          f"no frame recorded on {cm.name} for {gap.seconds:.3f} s, from "
                          f"{gap.start - cm.start:.6f} s to {gap.end - cm.start:.6f} s: "
                          f"longer than every heartbeat or guarding limit running there "
                          f"(at most {gap.limit_s:.3f} s), then the channel goes on: the "
                          "log cannot tell a recorder that was off or a clock step from a "
                          f"network that was off; {who} not judged for it "
                          "(limits count again from its end)",
                          gap.end_idx, gap.end_line or None)


"""The bus-wait allowance q(F) of SPEC §9.1.6, shared by D002 and E001: a frame that
waited for the bus makes the interval to the next frame of its producer look short."""

from __future__ import annotations

import numpy as np

from nmtcheck.timeline.model import ChannelModel, InputModel

EPS = 1e-9
WINDOW = 256  # q looks back over at most this many frames (F and the 255 before it)


def bus_waits(model: InputModel, cm: ChannelModel, idxs: np.ndarray) -> np.ndarray:
    """q(F) for the frames at file positions `idxs`: how long each may have waited for
    the bus, from the back-to-back run it ends (0: none, or no d8 on the channel). One
    pass over the input's frame times, however many frames are asked about (a stream
    that breaks its inhibit time asks for each of its frames). The frames of the other
    channels of the input are left out: back to back means on one bus."""
    out = np.zeros(len(idxs))
    if not len(idxs):  # before d8, which reads every frame time of the channel
        return out
    decoded = model.decoded
    d8 = decoded.d8(cm.chan)
    if d8 is None:
        return out
    order = np.argsort(idxs, kind="stable")
    wanted = np.asarray(idxs, np.int64)[order]
    before = np.zeros(0)  # the channel's last WINDOW - 1 frame times before the chunk
    done = 0
    for chunk in decoded.frame_times:
        if done == len(wanted):
            break
        base, ts = int(chunk["base"][0]), chunk["ts"]
        upto = done + int(np.searchsorted(wanted[done:], base + len(ts), side="left"))
        rows: np.ndarray | None = None  # the channel's frames in the chunk (None: all)
        if "chan" in chunk:
            rows = np.flatnonzero(chunk["chan"] == cm.chan)
            ts = ts[rows]
        elif int(chunk["chan_one"][0]) != cm.chan:  # another channel's frames only
            done = upto  # (none is asked about: q 0 if one were)
            continue
        times = np.concatenate([before, ts])
        if upto > done:
            # a frame begins a run where it is not back to back with the one before it
            # (the first frame kept begins one: q never looks further back than WINDOW)
            begins = np.ones(len(times), bool)
            begins[1:] = np.diff(times) > 1.25 * d8 + EPS
            at = np.arange(len(times))
            run_start = np.maximum.accumulate(np.where(begins, at, 0))
            local = wanted[done:upto] - base
            pos = len(before) + (local if rows is None else np.searchsorted(rows, local))
            first = np.maximum(np.maximum(run_start[pos], pos - (WINDOW - 1)), 0)
            out[order[done:upto]] = np.where(first == pos, 0.0,
                                             times[pos] - times[first] + d8)
            done = upto
        before = times[-(WINDOW - 1):]
    return out

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
    that breaks its inhibit time asks for each of its frames). Read only for an input of
    one channel (the frame-time store has no channel)."""
    out = np.zeros(len(idxs))
    decoded = model.decoded
    d8 = decoded.d8(cm.chan)
    if d8 is None or decoded.channels > 1 or not len(idxs):
        return out
    order = np.argsort(idxs, kind="stable")
    wanted = np.asarray(idxs, np.int64)[order]
    before = np.zeros(0)  # the last WINDOW - 1 frame times before the chunk
    done = 0
    for chunk in decoded.frame_times:
        if done == len(wanted):
            break
        base, ts = int(chunk["base"][0]), chunk["ts"]
        upto = done + int(np.searchsorted(wanted[done:], base + len(ts), side="left"))
        times = np.concatenate([before, ts])
        if upto > done:
            # a frame begins a run where it is not back to back with the one before it
            # (the first frame kept begins one: q never looks further back than WINDOW)
            begins = np.ones(len(times), bool)
            begins[1:] = np.diff(times) > 1.25 * d8 + EPS
            at = np.arange(len(times))
            run_start = np.maximum.accumulate(np.where(begins, at, 0))
            pos = len(before) + (wanted[done:upto] - base)
            first = np.maximum(np.maximum(run_start[pos], pos - (WINDOW - 1)), 0)
            out[order[done:upto]] = np.where(first == pos, 0.0,
                                             times[pos] - times[first] + d8)
            done = upto
        before = times[-(WINDOW - 1):]
    return out

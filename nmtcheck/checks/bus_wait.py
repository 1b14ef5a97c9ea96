"""The bus-wait allowance q(F) of SPEC §9.1.6, shared by D002 and E001: a frame that
waited for the bus makes the interval to the next frame of its producer look short."""

from __future__ import annotations

from nmtcheck.timeline.model import ChannelModel, InputModel

EPS = 1e-9


def bus_wait(model: InputModel, cm: ChannelModel, idx: int) -> float:
    """q(F) for the frame at file position `idx`: how long it may have waited for the
    bus, from the back-to-back run it ends (0: none, or no d8 on the channel). Read only
    for an input of one channel (the frame-time store has no channel)."""
    decoded = model.decoded
    d8 = decoded.d8(cm.chan)
    if d8 is None or decoded.channels > 1:
        return 0.0
    times = decoded.times_before(idx + 1, 256)
    if len(times) < 2:
        return 0.0
    j = len(times) - 1
    while j > 0 and times[j] - times[j - 1] <= 1.25 * d8 + EPS:
        j -= 1
    return 0.0 if j == len(times) - 1 else float(times[-1] - times[j]) + d8

"""Traces shared by the rule and timeline tests: a realistic clean network and builders.

Kept in one place so that every rule group is checked against the same healthy
traffic (a false alarm in a CI gate is as bad as a miss).
"""

from __future__ import annotations

from pathlib import Path

START, STOP, PREOP, RESET4, END = 0.5, 3.0, 4.0, 4.5, 5.0

HEALTHY_NET = "".join(f"[nodes.{n}]\nheartbeat_ms = 100\n" for n in (2, 3, 4, 5, 6)) + (
    "[nodes.7]\nguard_time_ms = 200\nlife_time_factor = 3\n")


def jitter(i: int, node: int) -> float:
    """Deterministic heartbeat jitter, -2..+2 ms."""
    return ((i * 3 + node) % 5 - 2) / 1000.0


def hb(node: int, t0: float, t1: float, state: str = "7F", period: float = 0.1,
       jit: bool = False) -> list[tuple[float, str]]:
    """Heartbeats of `node` reporting `state` from t0 (inclusive) to t1 (exclusive)."""
    out = []
    i = 0
    while (t := t0 + period * i + (jitter(i, node) if jit else 0.0)) < t1 - 1e-9:
        out.append((round(t, 6), f"{0x700 + node:03X}#{state}"))
        i += 1
    return out


def healthy() -> list[tuple[float, str]]:
    """A realistic clean 5 s trace.

    Nodes 2, 3, 4 boot at 0 / 10 / 20 ms, node 5 is already running when the recording
    starts (heartbeat, no boot-up), node 6 is plugged in at 2.0 s and started directly,
    node 7 uses node guarding (every 200 ms, toggling). Heartbeats every 100 ms +-2 ms.
    SDO upload and LSS in PRE-OPERATIONAL, broadcast start at 0.5 s, TPDOs / RPDOs every
    20 ms only while OPERATIONAL (one TPDO still in flight 2 ms after the stop), an EMCY
    and its reset, SYNC and TIME, broadcast stop at 3.0 s, enter pre-operational at 4.0 s,
    reset node 4 at 4.5 s with its boot-up 60 ms later.
    """
    fr: list[tuple[float, str]] = [
        (START, "000#0100"), (2.2, "000#0106"), (STOP, "000#0200"), (PREOP, "000#8000"),
        (RESET4, "000#8104"),
    ]

    def code(t: float, start: float) -> str:
        return "7F" if t < start or t >= PREOP else "05" if t < STOP else "04"

    for n, boot in ((2, 0.0), (3, 0.01), (4, 0.02), (5, None), (6, 2.0)):
        start = 2.2 if n == 6 else START
        if boot is not None:
            fr.append((boot, f"{0x700 + n:03X}#00"))
        t0 = 0.045 if boot is None else boot + 0.1
        t1 = RESET4 if n == 4 else END
        fr += [(t, f[:4] + code(t, start)) for t, f in hb(n, t0, t1, jit=True)]
        t = start + 0.01 + n / 1000
        while t + 0.005 < STOP:
            fr.append((round(t, 6), f"{0x180 + n:03X}#{n:02X}00"))
            fr.append((round(t + 0.005, 6), f"{0x200 + n:03X}#0000"))
            t += 0.02
    fr.append((STOP + 0.002, "182#0200"))  # queued before the stop: within S001 grace_ms
    fr += [(RESET4 + 0.06, "704#00")] + hb(4, RESET4 + 0.16, END, jit=True)
    # node 7: node guarding only
    fr.append((0.03, "707#00"))
    for i, t in enumerate(x / 1000 for x in range(150, 5000, 200)):
        fr.append((t, "707#R"))
        fr.append((t + 0.002, f"707#{(i % 2) << 7 | int(code(t, START), 16):02X}"))
    fr += [(0.2, "602#4018100100000000"), (0.2005, "582#4318100143544D4E"),
           (2.1, "606#4000100000000000"), (2.1005, "586#4300100091010000"),
           (4.3, "604#2B17100064000000"), (4.3005, "584#6017100000000000"),
           (0.25, "7E5#5A00000000000000"), (0.2505, "7E4#5A5A000000000000"),
           (1.5, "083#1000010000000000"), (1.6, "083#0000000000000000"),
           (1.0, "100#00000000A537")]
    fr += [(x / 1000, "080#") for x in range(50, 5000, 50)]
    return sorted(fr, key=lambda x: x[0])


def profile(tmp_path: Path, text: str) -> str:
    path = tmp_path / "profile.toml"
    path.write_text('extends = "default"\n' + text)
    return str(path)

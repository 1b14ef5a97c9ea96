"""Human-readable report: per input its counts, findings grouped by channel and node, verdict."""

from __future__ import annotations

from itertools import groupby

from nmtcheck.engine import InputResult, summary


def _input_line(res: InputResult) -> list[str]:
    s = res.stats
    dur = (s.end or 0.0) - (s.start or 0.0)
    lines = [f"{s.path} ({s.format}): {s.frames} frames over {dur:.3f} s on "
             f"{len(s.channels)} channel(s) {', '.join(s.channels)}"]
    counts = [f"skipped records: {s.skipped}"
              + (f" (first at line {', '.join(map(str, s.skipped_lines[:5]))})"
                 if s.skipped_lines else ""),
              f"extended frames: {s.extended}", f"error frames: {s.error_frames}",
              f"remote frames: {s.remote_frames}", f"CAN FD frames: {s.fd_frames}",
              f"non-frame records: {s.ignored}", f"DROPCOUNT dropped: {s.dropped}"]
    if s.backwards_timestamps:
        counts.append(f"timestamps going backwards: {s.backwards_timestamps}")
    lines.append("  " + ", ".join(counts))
    return lines


def render(results: list[InputResult], options: dict[str, object]) -> str:
    fail_on = str(options.get("fail_on", "error"))
    quiet = bool(options.get("quiet", False))
    out: list[str] = []
    for res in results:
        out += _input_line(res)
        start = res.stats.start or 0.0
        if not quiet:
            nodes = res.nodes()
            if nodes:
                out.append("  nodes: " + "; ".join(
                    f"{m.channel}/{m.node} {m.intervals[-1].state} ({m.error_control}"
                    + (f", {m.period_s * 1000:.0f} ms" if m.period_s else "") + ")"
                    for m in nodes))
        key = lambda f: (f.channel, -1 if f.node is None else f.node)  # noqa: E731
        for (channel, node), group in groupby(sorted(res.findings, key=key), key=key):
            out.append(f"  {channel} " + ("network" if node == -1 else f"node {node}") + ":")
            for f in group:
                where = f"line {f.line}" if f.line else f"frame {f.frame_index}"
                out.append(f"    {f.time - start:10.6f} s  {where:<12} {f.severity:<7} "
                           f"{f.rule} {f.name}: {f.message}")
        out.append("")
    counts = summary(results)
    total = sum(counts.values())
    failing = _failing(counts, fail_on)
    verdict = "FAIL" if failing else "PASS"
    out.append(f"{verdict}: {counts['error']} error(s), {counts['warning']} warning(s), "
               f"{counts['info']} info in {total} finding(s) (--fail-on {fail_on})")
    return "\n".join(out) + "\n"


def _failing(counts: dict[str, int], fail_on: str) -> bool:
    order = ["error", "warning", "info"]
    if fail_on == "never":
        return False
    return any(counts[s] for s in order[: order.index(fail_on) + 1])

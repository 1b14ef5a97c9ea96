r"""One line per finding for CI logs, grep and editors (`--format concise`).

`PATH:LINE: TIME CODE [severity] node N: message` — TIME in seconds from the input's
first frame (`frame N` in a log without timestamps); LINE is empty for binary formats
(`run.blf:: …`). A finding of the network rather than a node (C001, C002 on a frame of
the wrong length) says `network:`; a finding about the input itself (I-rules) has no
node part, and neither has one whose message names its node already (`no heartbeat
from node 3`: the node is not said twice). When an input has several channels the node
part names the channel too (`node 5 on can1:`, or `can1:` before a message naming the
node). Vim's `errorformat=%f:%l:\ %m` and Emacs' compilation mode follow these lines.
A verdict line ends the output.
"""

from __future__ import annotations

import re

from nmtcheck.reporters.common import (
    measured_mark,
    moment,
    node_label,
    omitted_lines,
    unreadable,
    verdict_line,
)
from nmtcheck.results import Finding, InputResult
from nmtcheck.safe_text import escape_lines


def finding_line(res: InputResult, f: Finding) -> str:
    several = len(res.stats.channels) > 1
    if f.channel is None:
        who = ""
    elif f.node is not None and re.search(rf"\bnode {f.node}\b", f.message):
        who = f"{f.channel}: " if several else ""  # the message names the node: not twice
    else:
        who = node_label(f.node) + (f" on {f.channel}" if several else "")
        who += ": "
    return (f"{res.stats.path}:{f.line or ''}: {moment(res, f.time, unit='s', f=f)} {f.rule} "
            f"[{f.severity}] {who}{f.message}")


def render(results: list[InputResult], options: dict[str, object]) -> str:
    lines = [f"{res.stats.path}:: cannot be checked: {res.error}"
             for res in unreadable(results)]
    lines += [finding_line(res, f) + measured_mark(f) for res in results for f in res.findings]
    lines += omitted_lines(results, options)
    lines.append("nmtcheck " + verdict_line(results, options))
    return escape_lines(lines) + "\n"  # a name's newline or ESC is shown, never sent

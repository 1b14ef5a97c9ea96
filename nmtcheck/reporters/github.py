"""GitHub Actions workflow commands: each finding becomes an annotation on the log's line.

`--format auto` picks this under Actions (GITHUB_ACTIONS=true). A plain verdict
line follows so the job log still reads on its own.
"""

from __future__ import annotations

from nmtcheck.reporters.common import (
    measured_mark,
    moment,
    omitted_lines,
    unreadable,
    verdict_line,
    where_label,
)
from nmtcheck.results import InputResult

COMMANDS = {"error": "error", "warning": "warning", "info": "notice"}


def escape_data(text: str) -> str:
    """The message part of a workflow command (GitHub's toolkit escaping)."""
    return text.replace("%", "%25").replace("\r", "%0D").replace("\n", "%0A")


def escape_property(text: str) -> str:
    """A `key=value` property: also `:` and `,`, which would end the value."""
    return escape_data(text).replace(":", "%3A").replace(",", "%2C")


def render(results: list[InputResult], options: dict[str, object]) -> str:
    lines = [f"::error file={escape_property(res.stats.path)},title=cannot be checked::"
             f"{escape_data(str(res.error))}" for res in unreadable(results)]
    for res in results:
        for f in res.findings:
            props = [f"file={escape_property(res.stats.path)}"]
            if f.line:
                props.append(f"line={f.line}")
            title = f"{f.rule} {f.name} ({where_label(f.channel, f.node)})"
            props.append(f"title={escape_property(title)}")
            message = f"{f.message} [at {moment(res, f.time, 3, f=f)}]{measured_mark(f)}"
            lines.append(f"::{COMMANDS[f.severity]} {','.join(props)}::{escape_data(message)}")
    lines += [f"::notice::{escape_data(line)}" for line in omitted_lines(results, options)]
    lines.append("nmtcheck " + verdict_line(results, options))
    return "\n".join(lines) + "\n"

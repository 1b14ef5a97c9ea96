#!/usr/bin/env python3
"""Coverage-guided fuzz target (atheris/libFuzzer) for one text reader, or all of them.

    python fuzz/fuzz_reader.py --format=FORMAT [libFuzzer options] [CORPUS_DIR...]
    python fuzz/fuzz_reader.py --format=FORMAT --seed=CORPUS_DIR

FORMAT is a text format (candump, asc, trc, candump-screen, csv, cl2000) or `all` (the
first input byte picks the reader). An input fails when the reader raises anything but an
InputError (exit 2 with one line) or when its counts do not account for every record line
(frames + skipped + non-frame records). `--seed` writes valid logs of the format to start
a corpus from. Options start with `--` because libFuzzer ignores those and hands them on
to the processes of `-jobs`/`-fork`. See fuzz/README.md.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import atheris

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "tests")]

with atheris.instrument_imports(include=["nmtcheck.readers"]):
    from nmtcheck.errors import InputError
    from nmtcheck.readers import format_module, open_input

    for _name in ("candump", "asc", "trc", "candump-screen", "csv", "cl2000"):
        format_module(_name)  # imported here, so that their code is instrumented

from hostile_logs import TEXT_WRITERS, format_of, network_frames, record_lines  # noqa: E402

TEXT_FORMATS = sorted({format_of(w) for w in TEXT_WRITERS})
SCRATCH = Path(tempfile.mkdtemp(prefix="nmtcheck-fuzz-", dir="/dev/shm"
                                if os.path.isdir("/dev/shm") else None)) / "input.log"


def write_seeds(corpus: Path, fmt: str) -> None:
    """Valid logs of the format (for `all`: of every format, behind their selector byte)."""
    corpus.mkdir(parents=True, exist_ok=True)
    for writer, write in TEXT_WRITERS.items():
        if fmt == "all":
            selector = bytes([TEXT_FORMATS.index(format_of(writer))])
            (corpus / f"seed-{writer}").write_bytes(selector + write(network_frames()))
        elif format_of(writer) == fmt:
            (corpus / f"seed-{writer}").write_bytes(write(network_frames()))


def check_one(data: bytes, fmt: str) -> None:
    """Read `data` as `fmt`; raise unless it is an input error or every record is counted."""
    SCRATCH.write_bytes(data)
    try:
        opened = open_input(str(SCRATCH), fmt)
        for _batch in opened.batches:
            pass
    except InputError as exc:
        if "\n" in str(exc):
            raise AssertionError(f"an exit-2 message of more than one line: {exc!r}") from None
        return
    s = opened.stats
    records = len(record_lines(fmt, data))
    if s.frames + s.skipped + s.ignored != records:
        raise AssertionError(f"{fmt}: {s.frames} frames + {s.skipped} skipped + {s.ignored} "
                             f"non-frame records, but {records} record lines")


def _option(name: str) -> str | None:
    """The value of `--name=VALUE` in argv (libFuzzer ignores `--` options)."""
    prefix = f"--{name}="
    return next((a[len(prefix):] for a in sys.argv[1:] if a.startswith(prefix)), None)


def main() -> None:
    fmt = _option("format") or ""
    if fmt not in (*TEXT_FORMATS, "all"):
        sys.exit(f"usage: fuzz_reader.py --format={{{','.join(TEXT_FORMATS)},all}} "
                 "[--seed=DIR | libFuzzer options and corpus directories]")
    seed_dir = _option("seed")
    if seed_dir is not None:
        write_seeds(Path(seed_dir), fmt)
        return

    def one_input(data: bytes) -> None:
        if fmt != "all":
            check_one(data, fmt)
        elif data:
            check_one(data[1:], TEXT_FORMATS[data[0] % len(TEXT_FORMATS)])

    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()

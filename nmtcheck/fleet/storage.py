"""Where logs and results live: any fsspec URL (s3://, gs://, az://, file://, plain paths).

Listing (globs, manifests), the object's identity (etag, size, mtime) for incremental
re-runs, the `--path-pattern` fields, and fetching a batch of objects concurrently into a
local directory: small logs are dominated by the latency of each GET, not by bandwidth.
Credentials come from the environment (AWS_*, GOOGLE_*, AZURE_*) as each filesystem reads
them; `--storage-option` refuses credential keys so that none travel in task arguments.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import stat
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError

UNSUPPORTED_SUFFIXES = (".mfe", ".mfm")  # CANedge encrypted MF4: needs the device's key
CREDENTIAL_WORDS = ("secret", "token", "password", "key", "credential", "sas", "account_key")
FETCH_THREADS = 16


@dataclass(frozen=True)
class FileInfo:
    """One log object: its URL as the user named it, and what identifies its content."""

    url: str
    size: int | None = None
    etag: str | None = None
    mtime: float | None = None  # seconds since the epoch (UTC)

    @property
    def fingerprint(self) -> str:
        """The object's content identity: the etag where the store has one, else size and
        modification time (local files)."""
        if self.etag:
            return f"etag:{self.etag}"
        return f"size:{self.size}:mtime:{self.mtime}"


def parse_storage_options(items: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """`--storage-option k=v` pairs; values true/false/ints/floats as such, nested keys with
    dots (`client_kwargs.endpoint_url=...`). Credential keys are refused: they would be
    copied into every task sent to the cluster (use the environment instead)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise UsageError(f"--storage-option {item}: expected KEY=VALUE, "
                             "e.g. --storage-option endpoint_url=http://minio:9000")
        last = key.rsplit(".", 1)[-1].lower()
        if any(w in last for w in CREDENTIAL_WORDS) and last not in ("use_ssl",):
            raise UsageError(f"--storage-option {key}: credentials are not taken on the command "
                             "line (they would travel in every task); set them in the "
                             "environment (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, ...)")
        target = out
        parts = key.split(".")
        for p in parts[:-1]:
            target = target.setdefault(p, {})
        target[parts[-1]] = _value(value)
    return out


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def filesystem(url: str, storage_options: dict[str, Any] | None = None) -> tuple[Any, str]:
    """The filesystem of `url` and the path within it: LocalFS for a local path given no
    storage option, else fsspec's. s3fs takes `endpoint_url` at the top level (as
    --storage-option gives it) and inside `client_kwargs`."""
    if not storage_options and os.sep == "/" and is_local(url):
        path = url[len("file://"):] if url.startswith("file://") else url
        return LOCAL_FS, LocalFS.strip(path)
    try:
        import fsspec
    except ImportError:
        raise UsageError(f"{url}: reading URLs needs fsspec; install it with pip install "
                         "'.[fleet]' in the nmtcheck checkout") from None
    from fsspec.core import split_protocol

    protocol, _ = split_protocol(url)
    try:
        fs, path = fsspec.core.url_to_fs(url, **(storage_options or {}))
    except ImportError as exc:
        extra = {"s3": "fleet", "s3a": "fleet", "gs": "gcs", "gcs": "gcs", "az": "azure",
                 "abfs": "azure", "abfss": "azure"}.get(protocol or "", "fleet")
        raise UsageError(f"{url}: {exc}; install it with pip install '.[{extra}]' in "
                         "the nmtcheck checkout"
                         ) from None
    except ValueError as exc:
        raise UsageError(f"{url}: {exc}") from None
    return fs, path


class LocalFS:
    """The calls a fleet run makes on local paths, answered as fsspec's LocalFileSystem
    answers them, without importing fsspec (issue 25): its import (asyncio, ssl,
    importlib.metadata) cost the driver 40 ms of CPU per run, more than the rest of its
    work on 8 logs, and the fork server as much before the first task. Globs follow
    fsspec's rules (`*`, `?`, `[..]` within a folder, hidden names included, `**` a whole
    folder level: zero or more folders); tests/test_fleet_overhead.py compares the two."""

    local = True

    @staticmethod
    def strip(path: str) -> str:
        """As fsspec's LocalFileSystem._strip_protocol: absolute, no trailing slash."""
        if path.startswith("~"):
            path = os.path.expanduser(path)
        path = os.path.abspath(path) if path else os.getcwd()
        return path.rstrip("/") or "/"

    def exists(self, path: str) -> bool:
        return os.path.exists(path)

    def isfile(self, path: str) -> bool:
        return os.path.isfile(path)

    def info(self, path: str) -> dict[str, Any]:
        """A path named as such: a link is described by its target."""
        out = os.stat(path, follow_symlinks=False)
        link = stat.S_ISLNK(out.st_mode)
        if link:
            out = os.stat(path, follow_symlinks=True)
        kind = ("directory" if stat.S_ISDIR(out.st_mode) else
                "file" if stat.S_ISREG(out.st_mode) else "other")
        return _entry(path, out, kind, out.st_size, link)

    def open(self, path: str, mode: str = "rb", encoding: str | None = None) -> Any:
        return open(path, mode, encoding=encoding)

    def makedirs(self, path: str, exist_ok: bool = False) -> None:
        os.makedirs(path, exist_ok=exist_ok)

    def rm(self, path: str) -> None:
        os.remove(path)

    def find(self, path: str) -> list[str]:
        """Everything below `path` but its folders, sorted (links are not followed)."""
        return sorted(p for p, e in self._walk(path.rstrip("/") or "/", None)
                      if e["type"] != "directory")

    def glob(self, pattern: str, detail: bool = True) -> dict[str, dict[str, Any]]:
        """The paths `pattern` matches (files, folders, links), with their info, sorted."""
        pattern = self.strip(pattern)
        parts = pattern.split("/")
        if any("**" in p and p != "**" for p in parts):
            raise ValueError("Invalid pattern: '**' can only be an entire path component")
        first = next(i for i, p in enumerate(parts) if _has_magic(p))
        root = "/".join(parts[:first]) or "/"
        rest = parts[first:]
        base = len(root.rstrip("/")) + 1
        found = {p: e for p, e in self._walk(root, None if "**" in rest else len(rest))
                 if _glob_match(rest, p[base:].split("/"))}
        if rest == ["**"] and os.path.isdir(root):  # `root/` matches `root/**` in fsspec
            found[root] = self.info(root)
        return dict(sorted(found.items()))

    def _walk(self, root: str, depth: int | None) -> Iterator[tuple[str, dict[str, Any]]]:
        """(path, info) of everything below `root`, `depth` levels down at most; as
        fsspec lists a folder: a link is described by itself (its size: its target's)
        and never entered."""
        todo = [(root, 1)]
        while todo:
            folder, level = todo.pop()
            try:
                it = os.scandir(folder)
            except OSError:  # not a folder, gone, unreadable: nothing below it
                continue
            with it:
                for d in it:
                    try:
                        info = _dir_entry(d)
                    except FileNotFoundError:
                        continue
                    yield info["name"], info
                    if info["type"] == "directory" and (depth is None or level < depth):
                        todo.append((info["name"], level + 1))


def _dir_entry(d: os.DirEntry[str]) -> dict[str, Any]:
    out = d.stat(follow_symlinks=False)
    link = d.is_symlink()
    kind = ("directory" if d.is_dir(follow_symlinks=False) else
            "file" if d.is_file(follow_symlinks=False) else "other")
    size = out.st_size
    if link:
        try:
            size = d.stat(follow_symlinks=True).st_size
        except OSError:
            size = 0
    return _entry(d.path, out, kind, size, link)


def _entry(path: str, out: os.stat_result, kind: str, size: int, link: bool
           ) -> dict[str, Any]:
    return {"name": path, "size": size, "type": kind,
            "created": getattr(out, "st_birthtime", out.st_ctime), "islink": link,
            "mtime": out.st_mtime}


def _glob_match(pattern: list[str], parts: list[str]) -> bool:
    """fsspec's glob on path segments: `**` takes zero or more segments (any number at
    the end), every other segment matches one (fnmatch)."""
    if not pattern:
        return not parts
    head = pattern[0]
    if head == "**":
        if len(pattern) == 1:
            return True
        return any(_glob_match(pattern[1:], parts[i:]) for i in range(len(parts)))
    return bool(parts) and fnmatch.fnmatchcase(parts[0], head) and _glob_match(
        pattern[1:], parts[1:])


LOCAL_FS = LocalFS()


def absolute(url: str) -> str:
    """A local path or file:// URL made absolute; other URLs as they are."""
    if not is_local(url):
        return url
    if url.startswith("file://"):
        return "file://" + os.path.abspath(url[len("file://"):])
    return os.path.abspath(url)


def is_local(url: str) -> bool:
    return _protocol(url) in (None, "file", "local")


def _protocol(url: str) -> str | None:
    """The URL's protocol as fsspec.core.split_protocol finds it (without importing fsspec:
    a local run never does)."""
    if "://" in url:
        protocol = url.split("://", 1)[0]
        if len(protocol) > 1:  # not a Windows drive
            return protocol
    if url.startswith("data:"):
        return "data"
    return None


def _info(fs: Any, url: str, entry: dict[str, Any]) -> FileInfo:
    etag = entry.get("ETag") or entry.get("etag") or entry.get("md5Hash") or None
    mtime: Any = entry.get("mtime") or entry.get("LastModified") \
        or entry.get("last_modified") or entry.get("updated") or entry.get("created")
    if mtime is not None and hasattr(mtime, "timestamp"):
        mtime = mtime.timestamp()
    elif isinstance(mtime, str):
        from datetime import datetime

        try:
            mtime = datetime.fromisoformat(mtime.replace("Z", "+00:00")).timestamp()
        except ValueError:
            mtime = None
    size = entry.get("size")
    return FileInfo(url, int(size) if size is not None else None,
                    str(etag).strip('"') if etag else None,
                    float(mtime) if mtime is not None else None)


def _unstrip(url: str, fs: Any, path: str) -> str:
    """The URL of a listed path: the protocol the user wrote, local paths absolute (a
    worker has another working directory, and a re-run from elsewhere must find the same
    log under the same name)."""
    if is_local(url):
        return ("file://" if url.startswith("file://") else "") + os.path.abspath(path)
    out: str = fs.unstrip_protocol(path)
    return out


def expand(sources: list[str], manifest: str | None,
           storage_options: dict[str, Any] | None) -> Iterator[FileInfo]:
    """Every log the arguments name, with size/etag/mtime: glob patterns are listed (with
    `**` across folders), plain URLs are looked up, a manifest gives one URL per line
    (an S3 Inventory CSV's bucket,key columns too) and is streamed, never held whole."""
    for src in sources:
        fs, path = filesystem(src, storage_options)
        if _has_magic(path) and not _exists(fs, path):  # `a [1].log` may be a file
            try:
                found = fs.glob(path, detail=True)
            except Exception as exc:  # noqa: BLE001 - s3fs/botocore raise many kinds
                raise UsageError(f"{src}: cannot list: {_reason(exc)}") from None
            names = sorted(p for p, e in found.items() if e.get("type") != "directory")
            if not names:
                raise UsageError(f"{src}: no log file matches this pattern")
            for p in names:
                yield _info(fs, _unstrip(src, fs, p), found[p])
            continue
        try:
            entry = fs.info(path)
        except FileNotFoundError:
            raise UsageError(f"{src}: no such file") from None
        except Exception as exc:  # noqa: BLE001 - s3fs/botocore raise many kinds
            raise UsageError(f"{src}: cannot list: {_reason(exc)}") from None
        if entry.get("type") == "directory":
            raise UsageError(f"{src}: is a directory (use a glob such as '{src.rstrip('/')}/**')")
        yield _info(fs, _unstrip(src, fs, path) if is_local(src) else src, entry)
    if manifest is not None:
        yield from _manifest(manifest, storage_options)


def _reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]


def check_exists(url: str, storage_options: dict[str, Any] | None, option: str) -> None:
    fs, path = filesystem(url, storage_options)
    try:
        found = fs.isfile(path)
    except Exception as exc:  # noqa: BLE001 - s3fs/botocore raise many kinds
        raise UsageError(f"{option} {url}: cannot read: {_reason(exc)}") from None
    if not found:
        raise UsageError(f"{option} {url}: no such file")


def _manifest(manifest: str, storage_options: dict[str, Any] | None) -> Iterator[FileInfo]:
    fs, path = filesystem(manifest, storage_options)
    try:
        handle = fs.open(path, "rt", encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"--manifest {manifest}: no such file") from None
    with handle as f:
        for lineno, raw in enumerate(f, 1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            url = _manifest_url(line)
            if url is not None and is_local(url):
                url = absolute(url)
            if url is None:
                raise UsageError(f"--manifest {manifest}:{lineno}: expected a URL or an "
                                 f"S3 Inventory 'bucket,key,...' line, got {line[:80]!r}")
            size = _inventory_size(line)
            yield FileInfo(url, size)


def _manifest_url(line: str) -> str | None:
    """A URL or path as is; an S3 Inventory CSV row `"bucket","key",...` as s3://bucket/key."""
    if "://" in line or not line.startswith('"'):
        return line
    cols = [c.strip('"') for c in line.split(",")]
    if len(cols) >= 2 and cols[0] and cols[1]:
        from urllib.parse import unquote

        return f"s3://{cols[0]}/{unquote(cols[1])}"
    return None


def _inventory_size(line: str) -> int | None:
    if not line.startswith('"'):
        return None
    cols = [c.strip('"') for c in line.split(",")]
    return int(cols[3]) if len(cols) > 3 and cols[3].isdigit() else None


def _exists(fs: Any, path: str) -> bool:
    try:
        return bool(fs.isfile(path))
    except Exception:  # noqa: BLE001 - then it is a pattern to list
        return False


def _has_magic(path: str) -> bool:
    return any(c in path for c in "*?[")


def complete(infos: list[FileInfo], storage_options: dict[str, Any] | None) -> list[FileInfo]:
    """Look up size/etag/mtime of entries a manifest named without them (concurrently:
    each is one HEAD request)."""
    def look(fi: FileInfo) -> FileInfo:
        if fi.etag is not None or fi.mtime is not None:
            return fi
        try:
            fs, path = filesystem(fi.url, storage_options)
            return _info(fs, fi.url, fs.info(path))
        except (FileNotFoundError, OSError, UsageError):
            return fi  # the task reports it as an input error

    if all(fi.etag is not None or fi.mtime is not None for fi in infos):
        return infos
    with ThreadPoolExecutor(FETCH_THREADS) as pool:
        return list(pool.map(look, infos))


class PathPattern:
    """`--path-pattern '{device}/{session}/{split}.MF4'`: fields taken from the end of each
    log's path (CANedge uploads to DEVICE/SESSION/SPLIT.MF4)."""

    FIELDS = ("device", "session", "split")

    def __init__(self, pattern: str | None) -> None:
        self.pattern = pattern
        self._re: re.Pattern[str] | None = None
        if pattern:
            parts = re.split(r"\{(\w+)\}", pattern)
            regex = ""
            for i, part in enumerate(parts):
                if i % 2 == 0:
                    regex += re.escape(part)
                elif f"(?P<{part}>" in regex:
                    raise UsageError(f"--path-pattern {pattern}: {{{part}}} appears twice")
                elif part not in self.FIELDS:
                    raise UsageError(f"--path-pattern {pattern}: unknown field {{{part}}} "
                                     f"(known: {', '.join('{' + f + '}' for f in self.FIELDS)})")
                else:
                    regex += f"(?P<{part}>[^/]+?)"
            self._re = re.compile(r"(?:^|/)" + regex + r"$", re.IGNORECASE)

    def fields(self, url: str) -> dict[str, str | None]:
        out: dict[str, str | None] = dict.fromkeys(self.FIELDS)
        if self._re is not None:
            m = self._re.search(url.split("?", 1)[0])
            if m:
                out.update(m.groupdict())
        return out


def unsupported(url: str) -> str | None:
    """Why a log cannot be checked at all (not an error in it), or None."""
    if url.lower().endswith(UNSUPPORTED_SUFFIXES):
        return ("encrypted CANedge log (.MFE/.MFM): decrypt it first (CSS Electronics' "
                "mdf2decrypt) and check the .MF4")
    return None


def fetch_all(urls: list[str], directory: Path, storage_options: dict[str, Any] | None
              ) -> dict[str, tuple[str | None, str | None]]:
    """Each URL as a local path: local files are read where they are, remote objects are
    downloaded concurrently into `directory`. Returns url -> (local path, error text)."""
    out: dict[str, tuple[str | None, str | None]] = {}
    remote = []
    for url in urls:
        if is_local(url):
            out[url] = (url[len("file://"):] if url.startswith("file://") else url, None)
        else:
            remote.append(url)

    def get(item: tuple[int, str]) -> tuple[str, tuple[str | None, str | None]]:
        i, url = item
        target = directory / f"{i:06d}-{copy_name(url)}"
        try:
            fs, path = filesystem(url, storage_options)
            fs.get_file(path, str(target))
        except FileNotFoundError:
            return url, (None, "no such object")
        except Exception as exc:  # noqa: BLE001 - one object's failure is that input's error
            why = str(exc).replace(str(target), url)  # never the copy's temporary path
            return url, (None, f"cannot fetch: {type(exc).__name__}: {why}")
        return url, (str(target), None)

    out.update(map_in_daemons(get, list(enumerate(remote)), FETCH_THREADS))
    return out


def map_in_daemons(fn: Callable[[Any], Any], items: list[Any], threads: int) -> list[Any]:
    """[fn(x) for x in items], in up to `threads` daemon threads; `fn` catches what it
    can raise. An interrupt (Ctrl-C) in the calling thread returns at once: no item is
    started after it, and the downloads under way are left to the process's exit, not
    waited for (a pool's threads are joined at exit: Ctrl-C waited for every object
    queued, then for an MF4 of gigabytes to arrive)."""
    import threading

    results: list[Any] = [None] * len(items)
    todo = iter(enumerate(items))
    lock = threading.Lock()
    finished = threading.Semaphore(0)
    stopped = threading.Event()

    def work() -> None:
        while not stopped.is_set():
            with lock:
                item = next(todo, None)
            if item is None:
                return
            try:
                results[item[0]] = fn(item[1])
            finally:
                finished.release()

    workers = [threading.Thread(target=work, name="nmtcheck-fetch", daemon=True)
               for _ in range(min(threads, len(items)))]
    for t in workers:
        t.start()
    try:
        for _ in items:
            finished.acquire()
    finally:
        stopped.set()
    for t in workers:  # all done: they end now (a forked parse worker wants no thread)
        t.join()
    return results


COPY_NAME_BYTES = 120  # S3 keys may be 1024 bytes, a local file name 255


def copy_name(url: str) -> str:
    """The local name of a fetched object's copy: its base name (the suffixes tell a
    compressed log), cut from the left where it is too long for a file name."""
    name = os.path.basename(url.split("?", 1)[0]) or "log"
    while len(name.encode()) > COPY_NAME_BYTES:
        name = name[1:]
    return name


@contextlib.contextmanager
def local_copies(args: Sequence[str], storage_options: dict[str, Any] | None
                 ) -> Iterator[tuple[list[str], dict[str, str]]]:
    """The LOG arguments of a check without --results, each URL (s3://..., a glob of them
    too) replaced by local copies of the objects it names, fetched concurrently into a
    temporary directory that goes when the check is done; and {copy: URL}, the name the
    reports give each copy. An object that cannot be listed or fetched is a usage error
    (exit 2) before anything is checked. Local arguments are left as they are."""
    from nmtcheck.fleet.prestart import is_remote

    remote = [a for a in dict.fromkeys(args) if is_remote(a)]
    if not remote:
        yield list(args), {}
        return
    from nmtcheck.spool import removed_on_exit, spill_directory

    listed = {src: [fi.url for fi in expand([src], None, storage_options)] for src in remote}
    urls = list(dict.fromkeys(url for found in listed.values() for url in found))
    with removed_on_exit(spill_directory("nmtcheck-fetched-")) as tmp:
        fetched = fetch_all(urls, Path(tmp), storage_options)
        for url in urls:
            error = fetched[url][1]
            if error is not None:
                raise UsageError(f"{url}: {error}")
        out: list[str] = []
        names: dict[str, str] = {}
        for arg in args:
            for url in listed.get(arg, ()):
                copy = str(fetched[url][0])
                out.append(copy)
                names[copy] = url
            if arg not in listed:
                out.append(arg)
        yield out, names

"""File digests, atomic writes, exclusive locks between writers, and the checks an output path passes first.

A writer writes to a temporary file beside the target, then renames it over the target: a reader never sees a
half-written file. The temporary file's name says who owns it (`.<name>.<host>.<pid>.<random>.tmp`), so a
cleanup removes only temporaries whose writer is gone (`stale_temporaries`) and never another live writer's.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import re
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from dynplan.paths import PathError

#: This host, as a temporary file's name records it ('.' in a host name would split the fields).
_HOST = socket.gethostname().replace(".", "-")
#: `.<target>.<host>.<pid>.<random>.tmp[<suffix>]`
_TEMP_NAME = re.compile(r"\.([^.]+)\.(\d+)\.[A-Za-z0-9_]+\.tmp(\.[^.]*)?$")
#: A temporary file of another host counts as abandoned only after this long untouched (its writer cannot be
#: asked whether it is alive).
FOREIGN_STALE_S = 24 * 3600.0


@contextmanager
def atomic_path(path: str | os.PathLike, keep_suffix: bool = False) -> Iterator[Path]:
    """Yield a temporary path in `path`'s folder; on success it is renamed to `path`, on error removed.
    `keep_suffix`: the temporary name ends in `path`'s suffix too (for writers that pick a format by it)."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise PathError(f"{path}: is not a regular file; only regular files are written")
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = ".tmp" + (path.suffix if keep_suffix else "")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{_HOST}.{os.getpid()}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    tmp_path.chmod(0o666 & ~umask)  # mkstemp makes the file private; the result should be an ordinary file
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except OSError as error:
        if error.filename is None:  # a full disk or a write limit names no file: name the one being written
            raise OSError(error.errno, error.strerror, str(path)) from error
        raise
    finally:
        tmp_path.unlink(missing_ok=True)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically and return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


_THREADS: dict[str, threading.Lock] = {}
_THREADS_GUARD = threading.Lock()


def _thread_lock(lock_path: Path) -> threading.Lock:
    with _THREADS_GUARD:
        return _THREADS.setdefault(str(lock_path.resolve()), threading.Lock())


def is_held(lock_path: str | os.PathLike) -> bool:
    """Whether a writer holds the lock `exclusive(lock_path)` takes right now (another process or thread)."""
    lock_path = Path(lock_path)
    thread_lock = _thread_lock(lock_path)
    if not thread_lock.acquire(blocking=False):
        return True
    try:
        with open(lock_path, "r+") as lock:  # no file: no holder (a holder's file goes when it releases)
            try:
                fcntl.lockf(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                return True
            fcntl.lockf(lock, fcntl.LOCK_UN)
            return False
    except FileNotFoundError:
        return False
    finally:
        thread_lock.release()


@contextmanager
def exclusive(lock_path: str | os.PathLike, waiting: str | None = None) -> Iterator[None]:
    """Hold an exclusive lock on `lock_path` within the block: a POSIX lock, which other processes and NFS honour,
    plus a thread lock per path, since POSIX locks do not exclude the threads of one process. The file is created
    for the block and removed at its end, so no lock file outlives its writer. If another writer holds it, print
    `waiting` (with that writer's pid and host) once to stderr and wait for it."""
    lock_path = Path(lock_path)
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    with _thread_lock(lock_path):
        lock = _locked(lock_path, waiting)
        try:
            lock.seek(0)
            lock.truncate()
            lock.write(f"pid {os.getpid()} on {_HOST}\n")
            lock.flush()
            yield
        finally:
            lock_path.unlink(missing_ok=True)  # while held: a writer waiting on it finds it gone and locks anew
            fcntl.lockf(lock, fcntl.LOCK_UN)
            lock.close()


def _locked(lock_path: Path, waiting: str | None) -> IO[str]:
    """The lock file at `lock_path`, open and locked; when the writer before removed the file this one waited on,
    the lock is taken again on the file now at the path."""
    said = waiting is None
    while True:
        lock = open(lock_path, "a+")  # noqa: SIM115 (returned open: the caller's block closes it)
        try:
            try:
                fcntl.lockf(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                if not said:
                    lock.seek(0)
                    holder = lock.read().strip() or "unknown"
                    print(f"{waiting} (held by {holder}); waiting for it to finish", file=sys.stderr, flush=True)
                    said = True
                fcntl.lockf(lock, fcntl.LOCK_EX)
            if _same_file(lock, lock_path):
                return lock
        except BaseException:
            lock.close()
            raise
        lock.close()


def _same_file(lock: IO[str], path: Path) -> bool:
    """Whether the open `lock` is the file at `path` now (not one its holder removed)."""
    try:
        at_path = os.stat(path)
    except FileNotFoundError:
        return False
    held = os.fstat(lock.fileno())
    return (at_path.st_dev, at_path.st_ino) == (held.st_dev, held.st_ino)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def stale_temporaries(folder: str | os.PathLike, target_glob: str = "*") -> list[Path]:
    """Temporary files in `folder` (of targets matching `target_glob`) whose writer is gone: a process of this host
    that no longer runs, an unnamed owner (older files), or another host's file untouched for a day. A live
    writer's temporary file is never among them."""
    stale = []
    for tmp in sorted(Path(folder).glob(f".{target_glob}.*.tmp*")):
        owner = _TEMP_NAME.search(tmp.name)
        if owner is None:
            gone = True  # no owner recorded
        elif owner.group(1) == _HOST:
            gone = not _alive(int(owner.group(2)))
        else:
            try:
                gone = time.time() - tmp.stat().st_mtime > FOREIGN_STALE_S
            except FileNotFoundError:
                continue
        if gone:
            stale.append(tmp)
    return stale


def sha256_file(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes, as hex (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()

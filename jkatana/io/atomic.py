"""Atomic file output: write to a temporary file beside the target, then rename.

A reader (or a resumed batch) never sees a half-written file: either the old
file, or the complete new one. ``os.replace`` is atomic on POSIX within one
file system, which is why the temporary lives in the target's own folder.

The temporary is created private (``mkstemp``: mode 0600) and given the
permissions an ordinary ``open()`` would have given a new file — 0666 less
the process umask — just before the rename, so outputs are as readable as
any other file the user writes. Temporaries still being written are listed
in :data:`LIVE`, so that an interrupt (:mod:`jkatana.io.interrupt`) can remove
them before the process exits.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Iterator

#: Temporaries being written right now (removed by the interrupt handler).
LIVE: set[Path] = set()
_LOCK = threading.Lock()


@functools.cache
def file_mode() -> int:
    """The permission bits a new file gets under this process's umask (0666 & ~umask).

    Read once per process (``file_mode.cache_clear()`` re-reads it after the umask changes):
    ``os.umask`` can only be read by setting it, so the read holds the lock that keeps two threads
    from seeing each other's temporary value.
    """
    with _LOCK:
        umask = os.umask(0o022)
        os.umask(umask)
    return 0o666 & ~umask


_CLOSED = False


def remove_live() -> None:
    """Interrupt clean-up: remove every temporary still being written, and create no new one.

    After the first call, :func:`atomic_path` blocks instead of creating a
    temporary (the process is about to exit). The paths stay listed, so a
    second call removes a temporary that a writer re-created by opening its
    path after the first removal.
    """
    global _CLOSED
    with _LOCK:
        _CLOSED = True
        paths = list(LIVE)
    for p in paths:
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()


@contextlib.contextmanager
def atomic_path(path: str | Path, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; on success rename it to ``path``.

    The temporary keeps ``path``'s suffix (libraries that pick the format from
    the extension, like OpenEXR or Pillow, still work). On an exception the
    temporary is removed and ``path`` is left as it was.
    """
    path = Path(path)
    mode = file_mode()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = None
    while tmp_path is None:
        with _LOCK:  # created and listed at once: an interrupt in between would leave it behind
            if not _CLOSED:
                fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix or path.suffix or ".tmp",
                                           dir=path.parent)
                os.close(fd)
                tmp_path = Path(tmp)
                LIVE.add(tmp_path)
        if tmp_path is None:  # exiting after an interrupt: write nothing more
            time.sleep(1.0)
    try:
        yield tmp_path
        os.chmod(tmp_path, mode)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise
    finally:
        with _LOCK:
            LIVE.discard(tmp_path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


@contextlib.contextmanager
def atomic_folder(path: str | Path, *, exists_error=None) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it becomes ``path``, which must not exist.

    The folder's files appear together or not at all: they are written into a
    hidden temporary folder (listed in :data:`LIVE`, so an interrupt removes
    it), then ``path`` is claimed with ``mkdir`` (which fails if it exists or
    anyone made it meanwhile) and the temporary folder renamed onto that empty
    claim (``rename(2)`` replaces an empty folder atomically). Nothing is
    ever overwritten: an existing ``path`` raises ``exists_error()`` (default
    :class:`FileExistsError`) before or after the work. Permissions: the
    umask's, folders searchable where readable.
    """
    path = Path(path)
    fail = exists_error or (lambda: FileExistsError(17, "exists", str(path)))
    if path.exists() or path.is_symlink():
        raise fail()
    path.parent.mkdir(parents=True, exist_ok=True)
    with _LOCK:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        LIVE.add(tmp)
    claimed = False
    try:
        yield tmp
        mode = file_mode()
        for f in tmp.rglob("*"):
            os.chmod(f, (mode | ((mode & 0o444) >> 2)) if f.is_dir() else mode)
        os.chmod(tmp, mode | ((mode & 0o444) >> 2))
        try:
            os.mkdir(path)
        except FileExistsError:
            raise fail() from None
        claimed = True
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if claimed:
            with contextlib.suppress(OSError):
                path.rmdir()
        raise
    finally:
        with _LOCK:
            LIVE.discard(tmp)

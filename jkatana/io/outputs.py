"""Output paths checked before any work starts.

Every command names what it will write — files and folders — and passes
them, with the inputs it reads, to :func:`check_outputs` before it decodes,
fits or renders anything. A path that cannot be written (its folder is
read-only or is a file, the target is a folder, the name is ``..``), that
would overwrite one of the command's own inputs, that has the wrong
extension for what is written, or that two outputs of one command share,
is refused with one :class:`~jkatana.errors.InputError` naming the option.
The files themselves are then written atomically (:mod:`jkatana.io.atomic`).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from pathlib import Path
from typing import Iterable, Sequence

from jkatana.errors import InputError


@dataclasses.dataclass(frozen=True)
class Output:
    """One thing a command writes.

    - `path`: where.
    - `field`: the option that named it (``--output``), for the error message.
    - `suffixes`: the extensions accepted for a file (lower case, with the dot); empty: any.
    - `folder`: a folder the command writes into (created if missing) rather than a file.
    """

    path: str | Path
    field: str = "--output"
    suffixes: tuple[str, ...] = ()
    folder: bool = False


def check_path_text(value: str | Path, field: str) -> Path:
    """A path from the command line: refuses NUL bytes and empty names."""
    text = os.fspath(value)
    if "\x00" in text:
        raise InputError("a path may not contain a NUL byte", field=field)
    if not text.strip():
        raise InputError("empty path", field=field)
    return Path(text)


def _writable_folder(folder: Path, field: str, what: Path) -> None:
    """``folder`` exists as a writable directory, or can be created inside one."""
    probe = folder
    while not probe.exists():
        if probe.is_symlink():  # a dangling link: mkdir would fail
            raise InputError(f"{probe} is a broken symbolic link", path=what, field=field)
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{probe} is a file, not a folder", path=what, field=field)
    try:  # a real probe: os.access says yes to root on a read-only mount or a /proc folder
        fd, tmp = tempfile.mkstemp(prefix=".jkatana-probe.", dir=probe)
        os.close(fd)
        os.unlink(tmp)
    except OSError as err:
        raise InputError(f"the folder {probe} is not writable ({err.strerror})", path=what, field=field) from None


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.abspath(a) == os.path.abspath(b)


def check_outputs(outputs: Sequence[Output], inputs: Iterable[str | Path | None] = ()) -> list[Path]:
    """Check every output of one command before it starts; return their paths.

    Raises :class:`InputError` naming the option when an output cannot be
    written, is a folder where a file is written (or a file where a folder
    is), has an extension not in ``suffixes``, is one of ``inputs``, or
    coincides with another output.
    """
    ins = [check_path_text(p, "input") for p in inputs if p is not None]
    paths: list[Path] = []
    for out in outputs:
        path = check_path_text(out.path, out.field)
        if path.name in ("", ".", "..") and not out.folder:
            raise InputError(f"{str(out.path)!r} names a folder, not a file", path=out.path, field=out.field)
        if out.folder:
            if path.exists() and not path.is_dir():
                raise InputError("exists and is not a folder", path=path, field=out.field)
            _writable_folder(path, out.field, path)
        else:
            if path.is_dir():
                raise InputError("is a folder; give a file name", path=path, field=out.field)
            if out.suffixes and path.suffix.lower() not in out.suffixes:
                raise InputError(f"the extension must be {' or '.join(out.suffixes)} (what is written), "
                                 f"got {path.suffix or 'none'!r}", path=path, field=out.field)
            if path.exists() and not os.access(path, os.W_OK) and not os.access(path.parent, os.W_OK):
                raise InputError("is not writable", path=path, field=out.field)
            _writable_folder(path.parent, out.field, path)
            for src in ins:
                if _same(path, src):
                    raise InputError("is one of the command's inputs; it would be overwritten",
                                     path=path, field=out.field)
        for prev, other in zip(outputs, paths):
            if not (out.folder or prev.folder) and _same(path, other):
                raise InputError(f"the command would write two outputs to one file ({prev.field} and "
                                 f"{out.field})", path=path, field=out.field)
        paths.append(path)
    return paths


__all__ = ["Output", "check_outputs", "check_path_text"]

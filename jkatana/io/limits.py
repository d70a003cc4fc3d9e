"""Checked command-line numbers and memory-bounded requests.

Each command checks all of its numeric options in one place, before any work,
with :func:`number` (finite, sign, integer, upper bound), and estimates the
peak memory its request needs. :func:`require_memory` refuses, naming the
option and the estimate, a request that cannot fit the memory this process
may use: the smallest of the machine's available memory, the cgroup's
``memory.max`` (Linux control groups v2) and the address-space limit
(``RLIMIT_AS``), or the user's ``--max-memory``. Estimates are the arrays a
request allocates, counted from its sizes, so a refusal costs nothing.
"""

from __future__ import annotations

import math
import os
import resource
from pathlib import Path

from jkatana.errors import InputError

_UNITS = {"": 1, "b": 1, "k": 2 ** 10, "m": 2 ** 20, "g": 2 ** 30, "t": 2 ** 40}


def number(value, field: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           integer: bool = False, path=None):
    """``value`` if it is a finite number in range (``lo`` ≤ or <, ``hi`` ≤), else :class:`InputError`.

    ``None`` passes through (an option left at its default "unset"). ``path`` names the file the value
    came from, for a field of a file rather than an option.
    """
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"must be a number, got {value!r}", field=field, path=path)
    if not math.isfinite(value):
        raise InputError(f"must be finite, got {value!r}", field=field, path=path)
    if integer and value != int(value):
        raise InputError(f"must be an integer, got {value!r}", field=field, path=path)
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise InputError(f"must be {'>' if lo_open else '>='} {lo:g}, got {value!r}", field=field, path=path)
    if hi is not None and value > hi:
        raise InputError(f"must be <= {hi:g}, got {value!r}", field=field, path=path)
    return value


def numbers(values, field: str, **kw):
    """:func:`number` for each of a sequence (``nargs`` options); None passes through."""
    if values is None:
        return None
    return [number(v, field, **kw) for v in values]


def parse_size(text: str | int | float | None, field: str = "--max-memory") -> int | None:
    """``"4G"``, ``"512M"``, ``"1.5GiB"``, ``"1000000"`` → bytes (binary units); None → None."""
    if text is None:
        return None
    s = str(text).strip().lower()
    for suffix in ("ib", "b"):
        if s.endswith(suffix) and len(s) > len(suffix):
            s = s[: -len(suffix)]
            break
    unit = s[-1] if s and s[-1] in "kmgt" else ""
    try:
        value = float(s[:-1] if unit else s)
    except ValueError:
        raise InputError(f"not a size (e.g. 4G, 512M): {text!r}", field=field) from None
    if not math.isfinite(value) or value <= 0:
        raise InputError(f"must be a positive size, got {text!r}", field=field)
    return int(value * _UNITS[unit])


def _cgroup_limit() -> int | None:
    for p in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(p).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 2 ** 60:
            return int(text)
    return None


def memory_budget(max_memory: int | None = None) -> int:
    """Bytes this process may allocate: the smallest of available RAM, cgroup and RLIMIT_AS, and ``max_memory``."""
    limits = []
    try:
        import psutil

        limits.append(int(psutil.virtual_memory().available))
    except ImportError:  # pragma: no cover - psutil comes with dask
        limits.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    cg = _cgroup_limit()
    if cg is not None:
        limits.append(cg)
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft not in (resource.RLIM_INFINITY, -1) and soft > 0:
        limits.append(int(soft))
    env = os.environ.get("JKATANA_MAX_MEMORY")
    if env:
        limits.append(parse_size(env, "JKATANA_MAX_MEMORY"))
    if max_memory is not None:
        limits.append(int(max_memory))
    return min(limits)


def human(nbytes: float) -> str:
    """``3.2 GiB`` style."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(nbytes) < 1024 or unit == "PiB":
            return f"{nbytes:.3g} {unit}" if unit != "B" else f"{int(nbytes)} B"
        nbytes /= 1024
    return f"{nbytes:.3g} EiB"  # pragma: no cover


def require_memory(estimate: float, field: str, what: str, max_memory: int | None = None) -> None:
    """Refuse (naming ``field``) a request whose estimated peak ``estimate`` bytes exceeds the budget."""
    budget = memory_budget(max_memory)
    if estimate > budget:
        limit = "allowed by --max-memory" if max_memory is not None and budget == max_memory else "available"
        raise InputError(f"{what} needs about {human(estimate)} of memory, more than the {human(budget)} {limit}",
                         field=field)


#: Most spectral values (texels × wavelengths) one environment may hold: 2^28, 2 GiB as float64. A scene's
#: environment is held to it (``jkatana.render.scene.LIMITS["env_values"]``), and so are ``light build`` and
#: ``light convert``, whose time grows in proportion to it: a bound on the work, whatever the memory would
#: allow (a few minutes on a 2-core machine).
ENV_VALUES = 1 << 28


def require_work(count: float, field: str, what: str, limit: float = ENV_VALUES) -> None:
    """Refuse (naming ``field``) a request of ``count`` spectral values, estimated from its sizes, beyond ``limit``."""
    if count > limit:
        raise InputError(f"{what} is {count:.3g} spectral values (texels × wavelengths), more than the {limit:.3g} "
                         "one environment may hold (minutes of work); a coarser grid step or a "
                         "smaller resolution", field=field)


__all__ = ["number", "numbers", "parse_size", "memory_budget", "require_memory", "require_work", "human",
           "ENV_VALUES"]

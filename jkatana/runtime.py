"""How many threads XLA's CPU client runs one program on, chosen before JAX starts its backend.

JAX's CPU client sizes its intra-op thread pool once, from the process's CPU
affinity mask when the backend starts (the JAX maintainers, Hawkins 2020: the mask
is the supported way to limit it); no flag or config sets it. A region fit is a
chain of several hundred small XLA operations on arrays of ~10³ points. Over a
pool of two threads each hand-over wakes the other core, which on a virtual
machine can cost more than the operation and varies with the host's load; on one
thread the same fit takes less CPU and its wall time stays steady
(``benchmarks/bench_fit.py`` measures it). The fit-stage commands therefore start the
backend with a one-thread pool (``$JKATANA_XLA_THREADS``, default 1 there); the
render commands keep JAX's default, one thread per core, because a frame is split
across host devices that share that pool.
"""

from __future__ import annotations

import os
import sys

ENV_VAR = "JKATANA_XLA_THREADS"


def backend_started() -> bool:
    """Whether JAX's backend already exists in this process (its thread pool is then fixed)."""
    if "jax" not in sys.modules:
        return False
    from jax._src import xla_bridge

    return bool(getattr(xla_bridge, "_backends", None))


def _threads() -> set[int]:
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def parse_threads(value: int | str | None) -> int | None:
    """``value`` as a thread count: ``None``, ``""`` or ``"all"`` → None (every core); else an integer ≥ 1."""
    from jkatana.errors import InputError

    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "all")):
        return None
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise InputError(f"must be a whole number of threads or 'all', got {value!r}", field=ENV_VAR) from None
    if n < 1:
        raise InputError(f"must be >= 1 or 'all', got {n}", field=ENV_VAR)
    return n


def xla_threads(threads: int | str | None) -> bool:
    """Start JAX's CPU backend with an intra-op pool of ``threads`` threads (:func:`parse_threads`; None:
    JAX's default, one per core of the affinity mask). Returns whether the pool was sized here.

    The calling thread's affinity is narrowed to ``threads`` cores while the backend starts; then it and
    every thread the backend started are given the full mask back, so the pool has ``threads`` threads
    that may run on any core, and compilation and everything outside XLA still see every core. Does
    nothing where the backend has already started (its pool is fixed), where ``threads`` covers every core,
    or on a platform without affinity masks.
    """
    n = parse_threads(threads)
    if n is None or not hasattr(os, "sched_setaffinity") or backend_started():
        return False
    cores = sorted(os.sched_getaffinity(0))
    if n >= len(cores):
        return False
    import jax

    before = _threads()
    os.sched_setaffinity(0, cores[:n])
    try:
        jax.devices()  # starts the backend: its pool is sized from the narrowed mask
    finally:
        os.sched_setaffinity(0, cores)
        for tid in _threads() - before:
            try:
                os.sched_setaffinity(tid, cores)
            except OSError:  # a thread that has exited since
                pass
    return True


def cache_home():
    """jkatana's cache folder: ``$JKATANA_CACHE``, else ``~/.cache/jkatana`` (its disk caches and
    :func:`compile_cache`'s programs live under it)."""
    from pathlib import Path

    return Path(os.environ.get("JKATANA_CACHE") or Path.home() / ".cache" / "jkatana")


#: Environment variable that switches JAX's persistent compilation cache off (:func:`compile_cache`).
NO_CACHE_VAR = "JKATANA_NO_JAX_CACHE"


def compile_cache() -> str | None:
    """Keep XLA's compiled programs between runs: JAX's persistent compilation cache in the folder ``jax`` of
    jkatana's cache (``$JKATANA_CACHE``, else ``~/.cache/jkatana``), every program kept however quick to
    compile (a program is tens to hundreds of kB; the folder may be deleted at any time).

    A command runs tens to hundreds of small programs (eager array operations, per-region steps, a frame's
    passes) whose compilation together costs seconds; from the cache the second run of the same shapes pays
    tracing alone. Before JAX is imported this sets the ``JAX_*`` variables JAX reads its defaults from (so
    a batch's worker processes share the folder); afterwards it updates JAX's config, unless a cache folder
    is already set (a caller's own, e.g. the test suite's). JAX makes the folder at its first compilation (a
    command refused before any leaves nothing behind); where it cannot (a read-only home) every program is
    compiled. Does nothing with ``$JKATANA_NO_JAX_CACHE`` set. Returns the folder used.
    """
    if os.environ.get(NO_CACHE_VAR):
        return None
    root = cache_home() / "jax"
    settings = {"jax_compilation_cache_dir": str(root), "jax_persistent_cache_min_compile_time_secs": 0.0}
    if "jax" not in sys.modules:
        for name, value in settings.items():
            os.environ.setdefault(name.upper(), str(value))
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    import jax

    if jax.config.jax_compilation_cache_dir:
        return jax.config.jax_compilation_cache_dir
    for name, value in settings.items():
        jax.config.update(name, value)
    return str(root)

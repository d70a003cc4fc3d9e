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

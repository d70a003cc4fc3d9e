"""Shared helpers for benchmarks: timing, machine facts, records."""

from __future__ import annotations

import os
import platform
import resource
import statistics
import time
from typing import Any, Callable


def machine_facts() -> dict[str, Any]:
    """Cores, CPU model, memory, JAX backend/version and devices, GPU if any."""
    facts: dict[str, Any] = {
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    facts["cpu_model"] = line.split(":", 1)[1].strip()
                    break
        with open("/proc/meminfo") as f:
            facts["memory_gib"] = round(int(f.readline().split()[1]) / 2**20, 1)
    except OSError:
        pass
    try:
        import jax

        facts["jax_version"] = jax.__version__
        facts["jax_backend"] = jax.default_backend()
        facts["jax_devices"] = [str(d) for d in jax.devices()]
    except Exception as err:  # pragma: no cover - JAX missing is itself a fact
        facts["jax_error"] = repr(err)
    try:
        import subprocess

        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=10)
        facts["gpu"] = out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        facts["gpu"] = None
    return facts


def block(x):
    """Wait for JAX arrays in ``x`` (any pytree) to be computed."""
    try:
        import jax

        return jax.block_until_ready(x)
    except ImportError:  # pragma: no cover
        return x


def timeit(fn: Callable[[], Any], *, repeats: int = 7, warmup: int = 1,
           min_time: float = 0.0) -> dict[str, float]:
    """Median and spread of the wall time of ``fn()`` (results are blocked on).

    ``warmup`` calls are made first (they absorb JIT compilation). Returns
    seconds: median, min, max, interquartile range, and the repeat count.
    """
    for _ in range(warmup):
        block(fn())
    times = []
    t_start = time.perf_counter()
    while len(times) < repeats or (time.perf_counter() - t_start) < min_time:
        t0 = time.perf_counter()
        block(fn())
        times.append(time.perf_counter() - t0)
        if len(times) >= 1000:
            break
    q = statistics.quantiles(times, n=4) if len(times) >= 2 else [times[0]] * 3
    return {
        "median": statistics.median(times),
        "min": min(times),
        "max": max(times),
        "iqr": q[2] - q[0],
        "repeats": len(times),
    }


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MiB (Linux ru_maxrss is KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def record(benchmark: str, case: dict[str, Any], *, time_s: dict[str, float] | None = None,
           error: dict[str, float] | None = None, reference: str | None = None,
           **extra: Any) -> dict[str, Any]:
    """One result row: which benchmark, which case, time, error against ``reference``."""
    row: dict[str, Any] = {"benchmark": benchmark, "case": case}
    if time_s is not None:
        row["time_s"] = time_s
    if error is not None:
        row["error"] = error
    if reference is not None:
        row["reference"] = reference
    row.update(extra)
    row["peak_rss_mb"] = round(peak_rss_mb(), 1)
    return row

"""Shared helpers for benchmarks: timing, machine facts, records (ΔE2000: :func:`jkatana.spectral.delta_e_display`).

The record convention for accuracy–time studies is documented in
:mod:`benchmarks` (``benchmarks/__init__.py``).
"""

from __future__ import annotations

import functools
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from typing import Any, Callable


def machine_facts() -> dict[str, Any]:
    """Cores, CPU model, memory, JAX backend/version and devices, GPU if any; Mitsuba's toolchain
    (:func:`peer_facts`) when it is installed.

    A cloud VM's model name can be as bare as "AMD EPYC", which does not tell one generation from
    another (their per-core speed differs by 2× and more), so the CPU's family, model number and
    stepping and its widest SIMD extension (XLA's CPU code is vectorised to it) are recorded too."""
    facts: dict[str, Any] = {
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(),
        "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
    }
    try:
        with open("/proc/cpuinfo") as f:
            info: dict[str, str] = {}
            for line in f:
                if not line.strip():
                    break                                   # the first processor's block is enough
                key, _, value = line.partition(":")
                info[key.strip()] = value.strip()
        facts["cpu_model"] = info.get("model name")
        facts["cpu_family"] = info.get("cpu family")
        facts["cpu_model_number"] = info.get("model")
        facts["cpu_stepping"] = info.get("stepping")
        flags = set(info.get("flags", "").split())
        facts["cpu_simd"] = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), None)
        with open("/proc/meminfo") as f:
            facts["memory_gib"] = round(int(f.readline().split()[1]) / 2**20, 1)
    except OSError:
        pass
    try:
        import jax

        facts["jax_version"] = jax.__version__
        facts["jax_backend"] = jax.default_backend()
        facts["jax_devices"] = [str(d) for d in jax.devices()]
        facts["jax_device_kind"] = jax.devices()[0].device_kind
    except Exception as err:  # pragma: no cover - JAX missing is itself a fact
        facts["jax_error"] = repr(err)
    facts.update(peer_facts())
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=10)
        facts["gpu"] = out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        facts["gpu"] = None
    return facts


def peer_facts() -> dict[str, Any]:
    """Mitsuba 3's and Dr.Jit's versions and the LLVM that Dr.Jit's CPU backend loads, when Mitsuba is installed.

    Mitsuba's speed on the CPU depends on that LLVM as much as on the CPU (the same Dr.Jit kernels ran several
    times slower with an older libLLVM), so a ratio against Mitsuba is only read together with it. The LLVM version
    is asked in a subprocess, so that a benchmark process that never renders with Mitsuba does not start
    Dr.Jit's backend; once per process (a copy of the first answer after that)."""
    return dict(_peer_facts())


@functools.lru_cache(maxsize=1)
def _peer_facts() -> dict[str, Any]:
    from importlib import metadata

    facts: dict[str, Any] = {}
    try:
        facts["mitsuba_version"] = metadata.version("mitsuba")
        facts["drjit_version"] = metadata.version("drjit")
    except metadata.PackageNotFoundError:
        return {}
    try:
        out = subprocess.run([sys.executable, "-c", "import drjit; print(*drjit.detail.llvm_version(), sep='.')"],
                             capture_output=True, text=True, timeout=60)
        version = out.stdout.strip()
        facts["drjit_llvm"] = version if out.returncode == 0 and version and not version.startswith("-1") else None
    except (OSError, subprocess.SubprocessError):
        facts["drjit_llvm"] = None
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
    partial = os.environ.get(PARTIAL_ENV)
    if partial:  # the runner's side file: rows made before a timeout survive it
        try:
            with open(partial, "a") as f:
                f.write(json.dumps(row, default=_json_default) + "\n")
        except (OSError, TypeError, ValueError):
            pass
    return row


#: Environment variables the runner sets for a benchmark's subprocess.
PARTIAL_ENV = "JKATANA_BENCH_PARTIAL"
BUDGET_ENV = "JKATANA_BENCH_BUDGET_S"


def _json_default(x):
    try:
        import numpy as np

        if isinstance(x, np.generic):
            return x.item()
        if hasattr(x, "tolist"):
            return x.tolist()
    except ImportError:  # pragma: no cover
        pass
    return float(x)


def budget_s(default: float = math.inf) -> float:
    """This module's wall-clock budget in seconds, as given by the runner (``default`` if none)."""
    try:
        return float(os.environ[BUDGET_ENV])
    except (KeyError, ValueError):
        return default




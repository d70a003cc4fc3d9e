"""Throughput of the reflection models: M evaluations/s (pairs × wavelengths per second).

Cases (all jitted, CPU, the machine's cores as reported):

- ``model``: Hiraji and Hamon, ``camera`` (eqs. 1, 2) and ``brdf_cos`` (rendering
  form), 10⁶ (L, V) pairs × 61 wavelengths (10⁵ pairs in quick mode), float32
  and float64. The pairs are drawn half near the specular direction, half
  uniformly over the hemisphere (the models are branch-free, so the mix does
  not change the work). Pairs go through the jitted model in chunks of 2¹³,
  each producing its full ``(chunk, 61)`` output (as a renderer's tile or a
  fit's batch would). The chunk size matters more than anything else here:
  measured on this machine, exact Fresnel in float64 ran at ~440 M evals/s
  with 2¹³- and 2¹⁵-pair chunks but ~35 M/s with 2¹⁷ (a fresh 64 MB output
  buffer per call: page faults and cache misses dominate). Reductions inside
  the jitted function were also tried and are 2–5× *slower* on XLA's CPU
  backend. The float64 result is the reference for the float32 error
  (on the first chunk).
- ``fresnel``: F(n(λ), k(λ), θ) for every pair and wavelength: the exact
  real-arithmetic form (``fresnel_conductor``), the same physics in complex
  arithmetic (Born & Wolf amplitudes, jnp complex; the prototype's form), and
  Schlick's approximation. Error: max |F − F_exact(float64)| over all pairs ×
  wavelengths of iron (Johnson & Christy 1974).

Run: ``python -m benchmarks --only bench_models [--quick] -o /tmp/x.json``.
"""

from __future__ import annotations

import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._harness import machine_facts, record, timeit

jax.config.update("jax_enable_x64", True)

from jkatana.models import Conductor, fresnel_conductor, fresnel_schlick, normal_incidence, paper_models  # noqa: E402
from jkatana.models.reflectance import Hamon, Hiraji  # noqa: E402

NAME = "models"
CHUNK = 1 << 13  # pairs per jitted call: a (8192, 61) float64 output is 4 MB


def _log(msg: str) -> None:
    print(f"[bench_models] {msg}", file=sys.stderr, flush=True)


def sample_pairs(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` unit (L, V) pairs, float64: half near-specular (μ-scale jitter), half uniform."""
    rng = np.random.default_rng(seed)

    def hemi(m):
        u, v = rng.random(m), rng.random(m)
        z = u
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(2 * np.pi * v), r * np.sin(2 * np.pi * v), z], -1)

    L = hemi(n)
    V = hemi(n)
    half = n // 2
    mirror = np.stack([-L[:half, 0], -L[:half, 1], L[:half, 2]], -1) + 0.05 * rng.standard_normal((half, 3))
    mirror[:, 2] = np.abs(mirror[:, 2])
    V[:half] = mirror / np.linalg.norm(mirror, axis=-1, keepdims=True)
    return L, V


def _run_chunks(fn, *arrays):
    """Evaluate ``fn`` chunk by chunk (full ``(chunk, wl)`` outputs, blocked, then dropped)."""
    n = arrays[0].shape[0]
    for i in range(0, n, CHUNK):
        jax.block_until_ready(fn(*(a[i:i + CHUNK] for a in arrays)))


def _timed(fn, *arrays, repeats):
    """Wall time (harness) and CPU time of evaluating all chunks."""
    cpu = []

    def once():
        t0 = time.process_time()
        _run_chunks(fn, *arrays)
        cpu.append(time.process_time() - t0)

    t = timeit(once, repeats=repeats, warmup=1)
    t["cpu_median"] = float(np.median(cpu[1:] if len(cpu) > 1 else cpu))
    return t


def _fresnel_complex(cos_i, n, k):
    """Born & Wolf amplitudes in complex arithmetic (the prototype's form)."""
    cdt = jnp.complex64 if cos_i.dtype == jnp.float32 else jnp.complex128
    eta = (n + 1j * k).astype(cdt)
    c = cos_i.astype(cdt)
    cos_t = jnp.sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (jnp.abs(rs) ** 2 + jnp.abs(rp) ** 2)


def run(quick: bool = False) -> list[dict]:
    facts = machine_facts()
    cores = facts.get("cores")
    n_pairs = 100_000 if quick else 1_000_000
    repeats = 5 if quick else 7
    L64, V64 = sample_pairs(n_pairs)
    cond64 = Conductor.from_table("Fe-Johnson")
    n_wl = int(cond64.n.shape[-1])
    evals = n_pairs * n_wl
    load = os.getloadavg()[0]
    _log(f"{n_pairs} pairs x {n_wl} wavelengths, {cores} cores, load {load:.1f}")
    records = []

    # ---- models
    reference = {}
    for dtype in (jnp.float64, jnp.float32):
        L, V = jnp.asarray(L64, dtype), jnp.asarray(V64, dtype)
        cond = Conductor(cond64.n.astype(dtype), cond64.k.astype(dtype))
        hiraji, hamon = paper_models(dtype)
        for model in (hiraji, hamon):
            for method in ("camera", "brdf_cos"):
                fn = jax.jit(lambda l, v, m=model, meth=method: getattr(m, meth)(l, v, cond))
                t = _timed(fn, L, V, repeats=repeats)
                out = np.asarray(fn(L[:CHUNK], V[:CHUNK]), np.float64)
                key = (type(model).__name__, method)
                err = None
                if dtype == jnp.float64:
                    reference[key] = out
                else:
                    ref = reference[key]
                    live = ref > 1e-6 * ref.max()
                    err = {"max_rel": float(np.max(np.abs(out - ref)[live] / ref[live])),
                           "max_abs_over_peak": float(np.max(np.abs(out - ref)) / ref.max())}
                rate = evals / t["median"] / 1e6
                best = evals / t["min"] / 1e6
                _log(f"{key[0]:6s} {method:8s} {jnp.dtype(dtype).name}: {rate:8.1f} M evals/s median, "
                     f"{best:8.1f} best ({t['median'] * 1e3:.1f} ms)"
                     + ("" if err is None else f", float32 max rel err {err['max_rel']:.1e}"))
                records.append(record(NAME, {"what": "model", "model": key[0], "method": method,
                                             "dtype": jnp.dtype(dtype).name, "pairs": n_pairs,
                                             "wavelengths": n_wl},
                                      time_s=t, error=err,
                                      reference=None if err is None else "float64, same inputs",
                                      m_evals_per_s=rate, m_evals_per_s_best=best, cpu_s=t["cpu_median"],
                                      cores=cores, load_avg=load))

    # ---- Fresnel forms
    cos64 = np.clip(L64[:, 2], 0.0, 1.0)
    exact64 = None
    for dtype in (jnp.float64, jnp.float32):
        cos = jnp.asarray(cos64, dtype)
        n, k = cond64.n.astype(dtype), cond64.k.astype(dtype)
        f0 = normal_incidence(n, k)
        forms = {
            "exact_real": lambda c: fresnel_conductor(c[:, None], n, k),
            "exact_complex": lambda c: _fresnel_complex(c[:, None], n, k),
            "schlick": lambda c: fresnel_schlick(c[:, None], f0),
        }
        for form, f in forms.items():
            fn = jax.jit(f)
            t = _timed(fn, cos, repeats=repeats)
            n_eval = evals
            # error on a subsample, full (pairs, wl) arrays
            sub = cos[:20000]
            vals = np.asarray(jax.jit(f)(sub), np.float64)
            if exact64 is None:
                exact64 = np.asarray(jax.jit(lambda c: fresnel_conductor(c[:, None], cond64.n, cond64.k))(
                    jnp.asarray(cos64[:20000])))
            err = float(np.max(np.abs(vals - exact64)))
            rate = n_eval / t["median"] / 1e6
            best = n_eval / t["min"] / 1e6
            _log(f"fresnel {form:13s} {jnp.dtype(dtype).name}: {rate:8.1f} M evals/s median, {best:8.1f} best, "
                 f"max |err| {err:.2e}")
            records.append(record(NAME, {"what": "fresnel", "form": form, "dtype": jnp.dtype(dtype).name,
                                         "pairs": n_pairs, "wavelengths": n_wl},
                                  time_s=t, error={"max_abs": err},
                                  reference="exact real-arithmetic form, float64",
                                  m_evals_per_s=rate, m_evals_per_s_best=best, cpu_s=t["cpu_median"],
                                  cores=cores, load_avg=load))
    return records


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(quick="--quick" in sys.argv), default=float, indent=1))

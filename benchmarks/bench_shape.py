"""Bezier least-squares fit: time and memory against point count (10⁴ … 10⁶).

Each case fits a degree-3, 24×6-patch grid (73×19 control points) to N noisy
samples of a surface with a crease on a patch break (the shinogi situation),
by matrix-free preconditioned CG in JAX (float64). Reference: the error
against the noiseless surface on a 200×50 grid (the fit should approach the
noise-free surface as N grows) — error and time side by side. Peak RSS is
recorded by the harness (process-wide, so it is a running maximum).
"""

from __future__ import annotations

import sys

import numpy as np


def _surface(s, t):
    return 0.0035 - 0.01 * np.abs(t - 0.3) + 0.002 * np.sin(6 * s) * (1 - t)


def run(quick: bool) -> list[dict]:
    import jax

    jax.config.update("jax_enable_x64", True)
    from benchmarks._harness import record, timeit
    from jkatana.shape.bezier import fit_bezier

    counts = [10_000, 30_000, 100_000] if quick else [10_000, 30_000, 100_000, 300_000, 1_000_000]
    S, T = np.meshgrid(np.linspace(0, 1, 200), np.linspace(0, 1, 50), indexing="ij")
    truth = _surface(S, T)
    records = []
    for n in counts:
        rng = np.random.default_rng(n)
        s, t = rng.random(n), rng.random(n)
        z = _surface(s, t) + rng.normal(0, 5e-5, n)
        kw = dict(degree=3, breaks_s=np.linspace(0, 1, 25), breaks_t=[0, 0.3, 0.53, 0.77, 1.0],
                  smoothness=1e-5)
        fit_bezier(s, t, z, **kw)  # compile for this N
        stats = timeit(lambda: fit_bezier(s, t, z, **kw)[0], repeats=3 if n >= 300_000 else 5, warmup=0)
        surf, info = fit_bezier(s, t, z, **kw)
        err = surf(S.ravel(), T.ravel()).reshape(S.shape) - truth
        rec = record("bench_shape", {"stage": "bezier_fit", "n_points": n, "degree": 3,
                                      "patches": [24, 4]}, time_s=stats,
                     error={"max_abs_m": float(np.abs(err).max()),
                            "rms_m": float(np.sqrt(np.mean(err**2)))},
                     reference="noiseless surface on a 200×50 grid", n_points=n,
                     n_control=info.n_control, cg_iterations=info.iterations,
                     converged=info.converged,
                     basis_arrays_mb=round(n * 16 * (4 + 8) / 2**20, 1))
        records.append(rec)
        print(f"bench_shape: n={n} median {stats['median']:.3f} s, rms err "
              f"{np.sqrt(np.mean(err**2)) * 1e6:.2f} µm, CG {info.iterations}", file=sys.stderr)
    return records

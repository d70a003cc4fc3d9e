"""A/B of the Beckmann visible-slope inversion: ``python ab_halley.py micro [ROUNDS]`` or ``frame SPP ROUNDS``.

Variants: ``newton`` — the inversion before this change (Jakob's 2014 start, three Newton steps in the
erf domain with a bisection bracket, a final erfinv; copied below from ea6be70) and ``halley`` — the
current :func:`jkatana.models.lobes._beckmann_visible_slope` (the same start, two Halley steps).
One process, alternating per round, each compiled afresh (``jax.clear_caches``), so both see the same load.

- ``micro``: the operations of each (erf_inv, exp, log, divide in the lowered StableHLO), |CDF − u| of
  both on the test grid (float64), and float32 CPU ns per sample (process CPU, all threads: run it with
  one XLA thread) of the jitted slope inversion alone and of ``Beckmann(0.2).sample_facet`` on 2¹⁸
  random views (cos θ uniform) and uniforms, 20 calls per timing.
- ``frame``: the rough Beckmann α 0.2 iron sphere of ``ab.py`` (courtyard map 256², 256², 2×2 subpixels),
  the map's spectra by jkatana's own upsampling (``same_upsampling=False``: Mitsuba is not installed
  here): frame CPU seconds of seeds 1 and 2 after a warm-up, and noise ΔE2000(seed 1, seed 2)/√2.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def newton_slope(cot, u):
    """The inversion as it was (ea6be70: ``BECKMANN_NEWTON_STEPS = 3``)."""
    import jax
    import jax.numpy as jnp

    from jkatana.models.lobes import _COT_MAX, U_MAX

    dtype = cot.dtype
    eps = float(jnp.finfo(dtype).eps)
    cot = jnp.minimum(cot, _COT_MAX)
    c = jax.scipy.special.erf(cot)
    den = cot * (1.0 + c) + jnp.exp(-cot * cot) * (1.0 / math.sqrt(math.pi))
    z = jnp.where(cot >= 1.0, 1.0 / jnp.maximum(cot, 1.0), cot)
    at = z * (math.pi / 4 + 0.273 * (1.0 - z))
    theta = jnp.where(cot >= 1.0, at, math.pi / 2 - at)
    fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta))
    u = jnp.clip(u, 0.0, U_MAX)
    b = c - (1.0 + c) * jnp.exp(fit * jnp.log1p(-u))
    lo, hi = jnp.full_like(b, -1.0), c
    for _ in range(3):
        b = jnp.clip(jnp.where((b >= lo) & (b <= hi), b, 0.5 * (lo + hi)), eps - 1.0, 1.0 - eps)
        x = jax.scipy.special.erfinv(b)
        value = (cot * (1.0 + b) + jnp.exp(-x * x) * (1.0 / math.sqrt(math.pi))) / den - u
        slope = (cot - x) / den
        hi = jnp.where(value > 0, b, hi)
        lo = jnp.where(value > 0, lo, b)
        b = b - value / jnp.where(slope > 0, slope, 1.0)
    b = jnp.clip(jnp.where((b >= lo) & (b <= hi), b, 0.5 * (lo + hi)), eps - 1.0, 1.0 - eps)
    return jax.scipy.special.erfinv(b)


_VARIANTS = {}


def variants():
    """The two inversions, the current one taken from the module once (the A/B swaps the module's name)."""
    if not _VARIANTS:
        from jkatana.models import lobes

        _VARIANTS.update(newton=newton_slope, halley=lobes._beckmann_visible_slope)
    return dict(_VARIANTS)


def micro(rounds):
    import jax
    import jax.numpy as jnp
    from scipy.special import erf

    from jkatana.models import lobes

    n, calls = 2 ** 18, 20
    rng = np.random.default_rng(0)
    cz = rng.uniform(0, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sz = np.sqrt(1 - cz * cz)
    V = jnp.asarray(np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], -1), jnp.float32)
    U = jnp.asarray(rng.uniform(0, 1, (n, 2)), jnp.float32)
    cot = jnp.asarray(cz / np.maximum(0.2 * sz, cz / 1e4), jnp.float32)
    lobe = lobes.Beckmann(jnp.float32(0.2))
    orig = lobes._beckmann_visible_slope
    # accuracy on the inversion test's grid (float64)
    jax.config.update("jax_enable_x64", True)
    g_cot = np.concatenate([[0.0, 1e-6, 1e-3], np.geomspace(1e-2, 1e4, 200)])[:, None]
    g_u = np.linspace(0.0, 1.0 - 1e-7, 1001)[None]
    C, Ug = np.broadcast_arrays(g_cot, g_u)
    for name, fn in variants().items():
        x = np.asarray(fn(jnp.asarray(C, jnp.float64), jnp.asarray(Ug, jnp.float64)))
        c = np.minimum(C, 1e4)
        cdf = (c * (1 + erf(x)) + np.exp(-x * x) / np.sqrt(np.pi)) / (c * (1 + erf(c)) + np.exp(-c * c) / np.sqrt(np.pi))
        txt = jax.jit(fn).lower(jnp.zeros(8, jnp.float32), jnp.zeros(8, jnp.float32)).as_text()
        ops = {k: txt.count(p) for k, p in (("erf_inv", "chlo.erf_inv"), ("exp", "stablehlo.exponential "),
                                              ("log", "stablehlo.log"), ("divide", "stablehlo.divide"))}
        print(f"{name}: max |CDF − u| float64 on the test grid {np.max(np.abs(cdf - Ug)):.2e}; ops per sample "
              f"(lowered StableHLO) {ops}", flush=True)
    jax.config.update("jax_enable_x64", False)
    res = {k: {"slope": [], "facet": []} for k in variants()}
    for r in range(rounds):
        for name, fn in (variants().items() if r % 2 == 0 else reversed(list(variants().items()))):
            lobes._beckmann_visible_slope = fn
            jax.clear_caches()
            fs = jax.jit(lambda c, u: fn(c, u))
            ff = jax.jit(lambda V, u: lobe.sample_facet(V, u))
            for key, f, args in (("slope", fs, (cot, U[:, 0])), ("facet", ff, (V, U))):
                f(*args).block_until_ready()
                c0 = time.process_time()
                for _ in range(calls):
                    f(*args).block_until_ready()
                res[name][key].append((time.process_time() - c0) / calls / n * 1e9)
            print(f"round {r} {name}: slope {res[name]['slope'][-1]:.1f} ns, sample_facet "
                  f"{res[name]['facet'][-1]:.1f} ns per sample (CPU)  load {os.getloadavg()[0]:.1f}", flush=True)
    lobes._beckmann_visible_slope = orig
    for name, v in res.items():
        print(f"{name}: slope median {np.median(v['slope']):.1f} [{min(v['slope']):.1f}, {max(v['slope']):.1f}] ns; "
              f"sample_facet median {np.median(v['facet']):.1f} [{min(v['facet']):.1f}, {max(v['facet']):.1f}] ns")


def frame(spp, rounds):
    import jax

    import jkatana.render.frame as fm
    from jkatana.models import lobes
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    orig = fm.render_frame
    box = {}

    def wrapped(*a, **k):
        c0 = time.process_time()
        f = orig(*a, **k)
        box["cpu"] = time.process_time() - c0
        return f

    fm.render_frame = wrapped
    res = {k: [] for k in variants()}
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for r in range(rounds):
            for name, fn in (variants().items() if r % 2 == 0 else reversed(list(variants().items()))):
                lobes._beckmann_visible_slope = fn
                jax.clear_caches()
                imgs, cpus = {}, []
                for seed in (1, 1, 2):  # the first: compilation and warm-up
                    img, mask, _ = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2,
                                                     seed=seed, env_nodes=None, same_upsampling=False)
                    imgs[seed] = img
                    cpus.append(box["cpu"])
                noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
                res[name].append((noise, np.mean(cpus[1:])))
                print(f"round {r} {name:6s} spp {spp}: noise {noise:.4f} CPU {np.mean(cpus[1:]):.3f} "
                      f"load {os.getloadavg()[0]:.2f}", flush=True)
    ratios = [h[1] / n[1] for h, n in zip(res["halley"], res["newton"])]
    for name, v in res.items():
        n, c = np.array(v).T
        print(f"{name:6s} spp {spp}: noise {n.mean():.4f} frame CPU median {np.median(c):.3f} "
              f"[{c.min():.3f}, {c.max():.3f}]")
    print(f"per-round CPU ratio halley/newton: median {np.median(ratios):.3f} [{min(ratios):.3f}, {max(ratios):.3f}]")


if __name__ == "__main__":
    if sys.argv[1] == "micro":
        micro(int(sys.argv[2]) if len(sys.argv) > 2 else 6)
    else:
        frame(int(sys.argv[2]), int(sys.argv[3]))

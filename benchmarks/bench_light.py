"""Lighting benchmarks: load/upsample, the spectral sky, prefiltering, sampling, Fresnel basis.

Every row pairs time (and memory: peak of NumPy allocations in the case, from
tracemalloc, plus the process's peak RSS) with the error against the exact
counterpart:

- load + upsample a 1024×512 RGB map to 61 bands, per method — error: RGB →
  spectrum → RGB round trip (relative to each texel's max channel);
- the Hosek–Wilkie sky at 1024×512×61 — errors: the rasterised sun's power vs
  the solar table's disc integral, and the sky's luminous horizontal
  irradiance vs a map at twice the resolution;
- prefiltering (μ = 0.005…0.3) — error: lookups vs brute-force convolution of
  the same map at probe directions (sun included);
- environment / lobe / MIS sampling — error: relative standard deviation of
  the reflected-radiance estimate, vs quadrature;
- the Fresnel SVD basis of iron per rank — error: max |ΔF|.

Quick mode uses 256×512 maps and 7 bands where the full run uses 1024×512 and 61.
"""

from __future__ import annotations

import math
import sys
import time
import tracemalloc

import numpy as np

from benchmarks._harness import record, timeit
from jkatana.shared import shared_data

B = "bench_light"
ENVMAPS = str(shared_data("envmaps"))


def _log(msg):
    print(f"[bench_light] {msg}", file=sys.stderr, flush=True)


def _traced(fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, dt, peak / 2**20


def run(quick: bool = False) -> list[dict]:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from jkatana.light import hosek_wilkie_sky, load_envmap, sun_direction
    from jkatana.light import sky as S
    from jkatana.light.envmap import read_rgb_image
    from jkatana.light.prefilter import brute_force_convolution, fresnel_basis, prefilter
    from jkatana.light.upsampling import round_trip_error
    from jkatana.spectral import DEFAULT_GRID, WavelengthGrid, xyz_weights

    rows = []
    grid = WavelengthGrid(400, 700, 50) if quick else DEFAULT_GRID
    res = (256, 512) if quick else (512, 1024)

    # ---------------------------------------------------------------- load + upsample
    rgb_sample = read_rgb_image(f"{ENVMAPS}/sunrise.exr")[::4, ::4]
    methods = ["Mallett 2019", "Jakob 2019"] if quick else ["Jakob 2019", "Mallett 2019", "Smits 1999", "Flat"]
    for name in (["sunrise.exr"] if quick else ["sunrise.exr", "pedestrian_overpass_1k.hdr"]):
        for m in (methods if name == "sunrise.exr" else methods[:2]):
            _log(f"load {name} {m}")
            env, dt, mem = _traced(lambda: load_envmap(f"{ENVMAPS}/{name}", grid, upsampling=m))
            t = timeit(lambda: load_envmap(f"{ENVMAPS}/{name}", grid, upsampling=m), repeats=1, warmup=0)
            err = round_trip_error(rgb_sample, m, grid)
            rows.append(record(B, {"stage": "load+upsample", "map": name, "method": m,
                                   "shape": list(env.radiance.shape)},
                               time_s=t, error={"round_trip_rel_mean": err["mean"], "round_trip_rel_p99": err["p99"],
                                                "round_trip_rel_max": err["max"]},
                               reference="input RGB (spectrum → XYZ over the grid → linear sRGB)",
                               numpy_peak_mb=round(mem, 1)))
            del env

    # ---------------------------------------------------------------- sky
    for elev in ((30.0,) if quick else (5.0, 30.0, 70.0)):
        _log(f"sky {res} elev {elev}")
        env, dt, mem = _traced(lambda: hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, res, grid))
        t = timeit(lambda: hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, res, grid), repeats=1, warmup=0)
        no_sun = hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, res, grid, sun=False, ground=False, dtype=jnp.float64)
        with_sun = hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, res, grid, ground=False, dtype=jnp.float64)
        om = np.asarray(with_sun.solid_angles())
        disc = np.einsum("hw,hwl->l", om, np.asarray(with_sun.radiance - no_sun.radiance))
        exact = S.solar_disc_integral(grid.wavelengths, math.radians(elev), 3.0)
        g7 = WavelengthGrid(400, 700, 50)  # resolution check on 7 bands (memory)
        coarse = hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, res, g7, sun=False, ground=False, dtype=jnp.float64)
        fine = hosek_wilkie_sky(elev, 135.0, 3.0, 0.1, (2 * res[0], 2 * res[1]), g7, sun=False, ground=False,
                                dtype=jnp.float64)
        ybar = xyz_weights(g7)[:, 1]
        e_c = float(np.asarray(coarse.irradiance()) @ ybar)
        e_f = float(np.asarray(fine.irradiance()) @ ybar)
        rows.append(record(B, {"stage": "sky", "shape": [res[0], res[1], grid.size], "elevation": elev},
                           time_s=t, error={"sun_power_rel_max": float(np.max(np.abs(disc / exact - 1))),
                                            "sky_irradiance_Y_rel_vs_2x": abs(e_c / e_f - 1)},
                           reference="solar-table disc integral (64-pt Gauss–Legendre); sky at 2× resolution",
                           numpy_peak_mb=round(mem, 1)))
        del env, no_sun, with_sun, fine, coarse

    # ---------------------------------------------------------------- prefilter
    mus = (0.01, 0.05, 0.3) if quick else (0.005, 0.02, 0.05, 0.1, 0.3)
    env = hosek_wilkie_sky(35.0, 180.0, 3.0, 0.1, res, grid, dtype=jnp.float64)
    _log(f"prefilter {res} {mus}")
    pf, dt, mem = _traced(lambda: prefilter(env, mus))
    s = sun_direction(35.0, 180.0)
    probes = [s, s + [0.02, 0, 0], s + [0, 0.05, 0.03], [0, 1.0, 0], [0.3, 0.2, -0.5], [0.01, -0.2, -1]]
    probes = [np.asarray(p, float) / np.linalg.norm(p) for p in probes]
    for mu in pf.mus:
        errs_sun, errs_far = [], []
        t_ref = time.perf_counter()
        for k, d in enumerate(probes):
            ref = brute_force_convolution(env, d, mu)
            got = np.asarray(pf.lookup(jnp.asarray(d), mu))
            (errs_sun if k < 3 else errs_far).append(float(np.max(np.abs(got / ref - 1))))
        t_ref = (time.perf_counter() - t_ref) / len(probes)
        lvl = pf.levels[pf.mus.index(mu)]
        rows.append(record(B, {"stage": "prefilter", "source": [res[0], res[1], grid.size], "mu": mu,
                               "level": [lvl.height, lvl.width]},
                           time_s={"median": dt / len(pf.mus), "min": dt / len(pf.mus), "max": dt / len(pf.mus),
                                   "iqr": 0.0, "repeats": 1, "note": "stack time / number of μ"},
                           error={"rel_max_near_sun": max(errs_sun), "rel_max_elsewhere": max(errs_far)},
                           reference=f"brute-force convolution of the texel map ({t_ref:.2f} s per direction)",
                           numpy_peak_mb=round(mem, 1)))

    # ---------------------------------------------------------------- sampling
    from jkatana.light.sampling import (
        EnvSampler, frame_from_normal, reflected_radiance, reflected_radiance_quadrature, to_local,
    )
    from jkatana.models import Conductor, Gaussian, Hiraji

    g7 = WavelengthGrid(400, 700, 50)
    small = hosek_wilkie_sky(35.0, 180.0, 3.0, 0.1, (64, 128), g7, dtype=jnp.float64)
    sampler = EnvSampler.build(small)
    sampler_c = EnvSampler.build(small, compensate=True)
    key = jax.random.PRNGKey(0)
    sample_1m = jax.jit(lambda k: sampler.sample(k, 1_000_000))
    t = timeit(lambda: sample_1m(key), repeats=3)
    rows.append(record(B, {"stage": "env sampling", "map": [64, 128], "n": 1_000_000}, time_s=t))
    cond = Conductor.from_table("Fe-Johnson", g7, jnp.float64)
    V = jnp.array([0.3, 0.2, 0.9]) / jnp.linalg.norm(jnp.array([0.3, 0.2, 0.9]))
    sd = jnp.asarray(sun_direction(35.0, 180.0))
    ybar7 = xyz_weights(g7)[:, 1]
    for mu in (0.05, 0.2):
        model = Hiraji(mu=jnp.asarray(mu))
        brdf = lambda L, V_, model=model: model.brdf_cos(L, V_, cond)  # noqa: E731
        for where, n_w in (("sun in lobe", (V + sd) / jnp.linalg.norm(V + sd)),
                           ("sky only", jnp.array([0.0, 1.0, 0.3]) / jnp.linalg.norm(jnp.array([0.0, 1.0, 0.3])))):
            fr = frame_from_normal(n_w)
            Vl = to_local(fr, V)
            ref = float(np.asarray(reflected_radiance_quadrature(small, brdf, Vl, fr, min(16 * mu, math.pi))) @ ybar7)
            M = 128 if quick else 256
            keys = jax.random.split(jax.random.PRNGKey(5), M)
            for strategy, (ne, nl), smp, label in (("env", (16, 16), sampler, "env"),
                                                   ("lobe", (16, 16), sampler, "lobe"),
                                                   ("mis", (8, 8), sampler, "mis balance"),
                                                   ("mis", (8, 8), sampler_c, "mis balance + compensation"),
                                                   ("mis", (16, 16), sampler_c, "mis balance + compensation")):
                f = jax.jit(jax.vmap(lambda k, strategy=strategy, ne=ne, nl=nl, smp=smp: reflected_radiance(
                    k, small, smp, brdf, Vl, fr, Gaussian(jnp.asarray(mu)), ne, nl, strategy=strategy)))
                Y = np.asarray(f(keys)) @ ybar7
                t = timeit(lambda: f(keys), repeats=3)
                n_tot = ne if strategy == "env" else nl if strategy == "lobe" else ne + nl
                rows.append(record(B, {"stage": "reflected radiance", "mu": mu, "config": where,
                                       "strategy": label, "samples": n_tot},
                                   time_s={k2: v / M for k2, v in t.items() if k2 != "repeats"} | {"repeats": t["repeats"]},
                                   error={"bias_rel": float(Y.mean() / ref - 1),
                                          "bias_in_se": float((Y.mean() - ref) / (Y.std() / math.sqrt(M))),
                                          "rel_std_per_estimate": float(Y.std() / ref)},
                                   reference="polar Gauss–Legendre quadrature (256×256) of the same integrand"))

    # ---------------------------------------------------------------- Fresnel basis
    cond61 = Conductor.from_table("Fe-Johnson")
    c = jnp.linspace(0.0, 1.0, 1001)
    F = np.asarray(cond61.fresnel(c))
    for r in (1, 2, 3, 4, 5):
        t = timeit(lambda: fresnel_basis(cond61, r).basis, repeats=3)
        fb = fresnel_basis(cond61, r)
        E = np.asarray(fb.reconstruct(c)) - F
        rows.append(record(B, {"stage": "fresnel basis", "material": "Fe-Johnson", "rank": r},
                           time_s=t, error={"max_abs": float(np.abs(E).max()),
                                            "rel_frobenius": float(np.linalg.norm(E) / np.linalg.norm(F))},
                           reference="conductor Fresnel F(cos θ, λ) on 1001 cos θ × 61 λ"))
    return rows

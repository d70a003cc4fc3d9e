"""Per-sample cost of the reference shader's parts on the peer sphere's own pixels: ``python prof.py [REPEATS]``.

Renders the peer sphere once (rough Beckmann α 0.2 iron, courtyard 256², 256², 2×2 subpixels, 8 spp,
jkatana's own upsampling) capturing the shader's inputs, then times jitted kernels on those pixels
(process CPU s per call, median of REPEATS, ns per pixel-sample): the whole ``shade`` at 8 and 16
lobe + environment samples, and each part of one lobe sample and one environment sample alone.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def capture():
    import jkatana.render.frame as fm
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    box = {}
    orig = fm._dispatch

    def wrapped(plan, mat, env, lights, px, cmf, key, n_dev, chunk, occluders, ids, caps_only=False):
        if not caps_only and plan.mode == "reference":
            box.update(plan=plan, mat=mat, env=env, px=px, cmf=cmf, key=key, ids=ids)
        return orig(plan, mat, env, lights, px, cmf, key, n_dev, chunk, occluders, ids, caps_only)

    fm._dispatch = wrapped
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        mc.render_jkatana(env, alpha=0.2, size=256, samples=8, supersample=2, seed=1, env_nodes=None,
                          same_upsampling=False)
    fm._dispatch = orig
    return box


def timeit(f, args, reps):
    import jax
    jax.block_until_ready(f(*args))
    out = []
    for _ in range(reps):
        c0 = time.process_time()
        jax.block_until_ready(f(*args))
        out.append(time.process_time() - c0)
    return float(np.median(out))


def main(reps):
    import dataclasses

    import jax
    import jax.numpy as jnp

    from jkatana.render import shading as sh
    from jkatana.render.points import mis_offset, uniforms

    b = capture()
    plan, mat, env, px, cmf, key, ids = (b[k] for k in ("plan", "mat", "env", "px", "cmf", "key", "ids"))
    px = jax.tree.map(lambda a: jnp.asarray(np.asarray(a)), px)
    P = px.normal.shape[0]
    ids = None if ids is None else jax.tree.map(lambda a: jnp.asarray(np.asarray(a)), ids)
    print(f"P = {P} pixels, plan {plan.mode} S {plan.samples} env {plan.n_env} rank {plan.fresnel_rank} "
          f"sub {plan.subpixels}; load {os.getloadavg()[0]:.2f}", flush=True)
    res = {}
    for S in (8, 16):
        pl = dataclasses.replace(plan, samples=S)
        f = jax.jit(lambda mat, env, px, cmf, key, ids, pl=pl: sh.shade(pl, mat, env, None, px, cmf, key, None, ids))
        t = timeit(f, (mat, env, px, cmf, key, ids), reps)
        res[S] = t
        print(f"shade S={S}: {t:.3f} s CPU/call  {t / (P * S) * 1e9:.1f} ns per pixel-sample pair", flush=True)
    print(f"per extra sample pair: {(res[16] - res[8]) / (8 * P) * 1e9:.1f} ns; fixed {2 * res[8] - res[16]:.3f} s")

    fr, Vl = sh._frame(px)
    norms = sh._norms(plan, mat, px)
    lobes = sh._lobes(plan, px, norms)
    sampler = sh._sampler(lobes)
    offset = mis_offset(key, P, Vl.dtype, plan, ids)
    _, r1, r2, re = uniforms(plan, offset, 3, Vl.dtype, ids)
    u = jnp.stack([r1, r2], -1)
    Ll, _ = sampler.sample(Vl, u, None)
    Lw = sh.to_world(Ll, *fr)
    uv = sh.env_uv(env, Lw)
    acc, combine = sh._accumulator(plan, mat, env, cmf, P, Vl.dtype)
    E = sh.bilinear_equirect_uv(env.channels, *uv)
    cos = jnp.clip(Ll[:, 2], 0, 1)
    parts = {
        "uniforms (Sobol + shift)": (lambda off, ids: uniforms(plan, off, 3, Vl.dtype, ids), (offset, ids)),
        "lobe sample_facet": (lambda V, u: sampler.sample_facet(V, u), (Vl, u)),
        "lobe sample (facet + reflect + pdf)": (lambda V, u: sampler.sample(V, u, None), (Vl, u)),
        "lobe pdf(L, V)": (lambda L, V: sampler.pdf(L, V), (Ll, Vl)),
        "lobe terms(L, V)": (lambda L, V: sh._fcos_terms(lobes, L, V)[0][0], (Ll, Vl)),
        "to_world": (lambda L: sh.to_world(L, *fr), (Ll,)),
        "to_local": (lambda L: sh.to_local(L, *fr), (Lw,)),
        "env_uv (atan2 pair)": (lambda L: sh.env_uv(env, L), (Lw,)),
        "env pdf_uv": (lambda a, b: env.sampler.pdf_uv(a, b), uv),
        "env sample_uniform2": (lambda r: env.sampler.sample_uniform2(r), (re,)),
        "bilinear lookup (9 ch)": (lambda a, b: sh.bilinear_equirect_uv(env.channels, a, b), uv),
        "combine (Fresnel table + fold)": (lambda c, E: combine(c, E), (cos, E)),
    }
    for name, (fn, args) in parts.items():
        t = timeit(jax.jit(fn), args, reps)
        print(f"{name:40s} {t / P * 1e9:7.1f} ns per pixel  load {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)

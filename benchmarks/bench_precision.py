"""Precision: float64 vs float32 vs float16 storage and evaluation of the shading.

A batch of shaded pixels of the paper's blended model (eq. 5: w·hiraji +
(1 − w)·hamon, rendering convention ``brdf_cos`` with the normalised lobes,
:mod:`jkatana.models.reflectance`) under spectral environment light:

    XYZ = Σλ [w f_hiraji + (1 − w) f_hamon](L, V, λ) cos θi · E(λ) · x̄ȳz̄(λ) Δλ,

with per-pixel inputs as a renderer stores them: directions L, V (a
G-buffer; V random up to 80°, L the mirror of V about a normal tilted by up
to 0.1 rad so most pixels sit inside the lobes), the reflectance map
(w ∈ [0, 1], μ0, μ1 ∈ [0.03, 0.1] rad) and the texel's spectral radiance E on
61 bands (real environment maps, upsampled as in :mod:`benchmarks.bench_spectral`;
values up to ~3·10⁴). Iron: Johnson & Christy (1974).

Study "precision" — reference: float64 storage and evaluation. Variants:
storage dtype (the arrays as kept in memory/textures) × evaluation dtype
(the arithmetic; storage is cast to it on read, as a shader does). Error:
ΔE2000 of the timed outputs after the same display transform; plus the
fraction of non-finite pixels of the eq. (1) *camera-units* evaluation with
χ = 79000 (which exceeds float16's largest finite value, 65504).
"""

from __future__ import annotations

import sys
import warnings

import numpy as np


def _log(msg: str) -> None:
    print(f"[bench_precision] {msg}", file=sys.stderr, flush=True)


def _inputs(n: int, rng: np.random.Generator):
    from benchmarks.bench_spectral import load_texels, upsample
    from jkatana.spectral import DEFAULT_GRID

    th = np.deg2rad(rng.uniform(0.0, 80.0, n))
    ph = rng.uniform(0.0, 2 * np.pi, n)
    V = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    tilt = rng.uniform(0.0, 0.1, n)
    tph = rng.uniform(0.0, 2 * np.pi, n)
    N = np.stack([np.sin(tilt) * np.cos(tph), np.sin(tilt) * np.sin(tph), np.cos(tilt)], -1)
    L = 2.0 * np.sum(N * V, -1, keepdims=True) * N - V
    L[:, 2] = np.maximum(L[:, 2], 1e-3)
    L /= np.linalg.norm(L, axis=-1, keepdims=True)
    w = rng.uniform(0.0, 1.0, n)
    mu0 = rng.uniform(0.03, 0.1, n)
    mu1 = rng.uniform(0.03, 0.1, n)
    E = upsample(load_texels(n, rng), DEFAULT_GRID)
    return {"L": L, "V": V, "w": w, "mu0": mu0, "mu1": mu1, "E": E}


def make_shader(n, k, W, eval_dtype):
    """Jitted shading: stored arrays (any dtype) → XYZ in ``eval_dtype``."""
    import jax
    import jax.numpy as jnp

    from jkatana.models import Conductor, Hamon, Hiraji, blend

    cond = Conductor(jnp.asarray(n, eval_dtype), jnp.asarray(k, eval_dtype))
    W = jnp.asarray(W, eval_dtype)

    @jax.jit
    def shade(s):
        s = {key: v.astype(eval_dtype) for key, v in s.items()}
        one = jnp.ones((), eval_dtype)
        cf = Hiraji(one, s["mu0"]).brdf_cos(s["L"], s["V"], cond)
        ct = Hamon(one, s["mu1"]).brdf_cos(s["L"], s["V"], cond)
        return (blend(s["w"], cf, ct) * s["E"]) @ W

    @jax.jit
    def camera(s):
        s = {key: v.astype(eval_dtype) for key, v in s.items()}
        return Hiraji(jnp.asarray(79000.0, eval_dtype), s["mu0"]).camera(s["L"], s["V"], cond)

    return shade, camera


def run(quick: bool) -> list[dict]:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from benchmarks._harness import record, timeit
    from jkatana.spectral import delta_e_display
    from jkatana.spectral import DEFAULT_GRID, load_optical_constants, xyz_weights

    rng = np.random.default_rng(7)
    n_pix = 2**13 if quick else 2**16
    repeats = 5 if quick else 9
    min_time = 0.3 if quick else 1.5
    inputs = _inputs(n_pix, rng)
    n, k = load_optical_constants("Fe-Johnson").on_grid(DEFAULT_GRID)
    W = xyz_weights(DEFAULT_GRID)

    f64, f32, f16, bf16 = jnp.float64, jnp.float32, jnp.float16, jnp.bfloat16
    ref_shade, ref_cam = make_shader(n, k, W, f64)
    stored64 = {key: jnp.asarray(v, f64) for key, v in inputs.items()}
    xyz_ref = np.asarray(ref_shade(stored64))
    cam_ref = np.asarray(ref_cam(stored64))
    variants = [(f64, f64), (f32, f32), (f16, f32), (bf16, f32), (f16, f16)]
    rows = []
    for storage, ev in variants:
        sname, ename = jnp.dtype(storage).name, jnp.dtype(ev).name
        label = f"{sname} storage, {ename} eval"
        stored = {key: jnp.asarray(v, storage) for key, v in inputs.items()}
        with warnings.catch_warnings():  # χ = 79000 overflows float16 on purpose
            warnings.simplefilter("ignore", RuntimeWarning)
            shade, cam = make_shader(n, k, W, ev)
        t = timeit(lambda: shade(stored), repeats=repeats, warmup=1, min_time=min_time)
        out = np.asarray(shade(stored), np.float64)
        err = delta_e_display(xyz_ref, out)
        err.pop("exposure"), err.pop("pixels")  # not errors
        finite = np.all(np.isfinite(out), axis=-1)
        err["nonfinite_frac"] = float(1.0 - finite.mean())
        ok = finite & np.all(np.isfinite(xyz_ref), -1)
        err["xyz_rel_max"] = float(np.max(np.abs(out[ok] - xyz_ref[ok])) / np.max(np.abs(xyz_ref))) \
            if ok.any() else float("nan")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            c = np.asarray(cam(stored), np.float64)
        err["camera_units_nonfinite_frac"] = float(1.0 - np.all(np.isfinite(c), -1).mean())
        cf = np.all(np.isfinite(c), -1)
        err["camera_units_rel_max"] = float(np.max(np.abs(c[cf] - cam_ref[cf])) / np.max(np.abs(cam_ref))) \
            if cf.any() else float("nan")
        storage_mb = sum(np.asarray(v).nbytes for v in stored.values()) / 2**20
        is_ref = storage is f64 and ev is f64
        rows.append(record("bench_precision", {"storage": sname, "eval": ename, "pixels": n_pix},
                           time_s=t, error=err, reference="float64 storage and evaluation",
                           study="precision", variant=label, error_metric="dE2000_mean", items=n_pix,
                           tolerance=1.0, is_reference=is_ref, storage_mib=round(storage_mb, 2),
                           note=f"inputs {storage_mb:.1f} MiB"))
        _log(f"{label}: dE mean {err['dE2000_mean']:.4g} p95 {err['dE2000_p95']:.4g}, non-finite "
             f"{err['nonfinite_frac']:.3g}, camera non-finite {err['camera_units_nonfinite_frac']:.3g}, "
             f"{t['median'] / n_pix * 1e9:.1f} ns/pixel")
    return rows

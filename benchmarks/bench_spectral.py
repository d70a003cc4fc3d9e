"""Spectral sampling and Fresnel approximations: error (ΔE2000) against time per pixel.

What is evaluated is the core of every shaded pixel of a polished blade: the
light of one environment texel reflected by iron at one angle,

    XYZ = Σλ F(n(λ), k(λ), θ) · E(λ) · x̄ȳz̄(λ) Δλ       (paper eqs. 1 and 6),

for a batch of pixel evaluations with random angles θ ∈ [0°, 89°] and random
texels of real environment maps (Poly Haven, CC0; ``shared_data("envmaps")``).
The maps are RGB, so each texel is upsampled to a spectrum on each grid with
the renderer's default method, :func:`jkatana.light.upsampling.rgb_to_spectrum`
``"Jakob 2019"`` (Jakob & Hanika, "A Low-Dimensional Function Space for
Efficient Spectral Upsampling", CGF 38(2), 2019), whose colour is the texel's
sRGB colour. Iron: Johnson & Christy (1974).

Study "spectral sampling" — reference: 61 bands (400–700 nm every 5 nm, the
paper's grid), evaluated in float64:

- K bands (31, 16, 8): n, k and the texel spectra point-sampled at K
  wavelengths; XYZ with *proper* quadrature weights Hᵀ·W₆₁ (H: linear
  interpolation from the K grid to the 61 grid), i.e. the integral of the
  piecewise-linear spectrum against the CMFs, not a coarse Riemann sum of them;
- 301 bands (1 nm): measured against the same reference, it shows the
  reference's own sampling error;
- RGB (3), per-channel optical constants: n, k averaged over 400–500,
  500–600, 600–700 nm, F evaluated per channel and multiplied with the
  texel's RGB, as RGB renderers do (the texel's RGB is the colour of its
  spectrum, so with F = 1 the two agree and only the RGB product is measured);
- RGB (3), tabulated F colour: the sRGB colour of the spectral F(θ)·D65,
  tabulated over 256 values of cos θ (a careful RGB renderer);
- rank-r basis (r = 1…5): :func:`jkatana.light.prefilter.fresnel_basis`, the
  SVD of iron's F(cos θ, λ) tabulated at 2049 angles, F ≈ Σᵣ cᵣ(θ) bᵣ(λ);
  each texel's XYZ of bᵣ(λ)E(λ) is baked once (as
  :func:`~jkatana.light.prefilter.project_on_basis` does; timed separately as
  ``precompute_s``), a pixel then costs r table look-ups and 3r
  multiply–adds — the interactive path's scheme.

Study "Fresnel approximation" — 61 bands throughout, reference exact Fresnel
(Born & Wolf): Schlick (1994) with F0 = F(0°) per band, and the rank-r
reconstruction of F(θ, λ). Errors: ΔE2000 of the pixels and the maximum
absolute error of F over θ ∈ [0°, 90°] and the 61 bands.

Times: jitted float32 evaluation of the whole batch (gather of the texel's
data included), median over repeats, reported per pixel. Errors: of exactly
the timed float32 outputs against the float64 reference, after the same
display transform (exposure: the reference's 99th-percentile Y → 1, sRGB).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from jkatana.shared import shared_data

ENVMAPS = ("city", "sunset", "forest", "interior")
ENV_DIR = str(shared_data("envmaps"))
N_COS_TABLE = 256


def _log(msg: str) -> None:
    print(f"[bench_spectral] {msg}", file=sys.stderr, flush=True)


def load_texels(count: int, rng: np.random.Generator, names=ENVMAPS) -> np.ndarray:
    """``count`` random linear-sRGB texels from real environment maps (negatives clipped to 0)."""
    from jkatana.io.exr import read_rgb

    per = -(-count // len(names))
    out = []
    for name in names:
        img = np.asarray(read_rgb(f"{ENV_DIR}/{name}.exr"), np.float64).reshape(-1, 3)
        out.append(img[rng.integers(0, img.shape[0], per)])
    return np.maximum(np.concatenate(out)[:count], 0.0)


def upsample(rgb: np.ndarray, grid) -> np.ndarray:
    """Texel RGB → spectral radiance on ``grid`` (the renderer's default, Jakob & Hanika 2019), float64."""
    from jkatana.light.upsampling import rgb_to_spectrum

    return np.asarray(rgb_to_spectrum(rgb, "Jakob 2019", grid), np.float64)


def interp_matrix(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """H with ``H @ values_src = linear interpolation of values at dst``, shape ``(len(dst), len(src))``."""
    return np.stack([np.interp(dst, src, np.eye(len(src))[i]) for i in range(len(src))], axis=-1)


def lerp_table(table, cos):
    """Linear interpolation of ``table`` (T, ...) sampled uniformly on cos θ ∈ [0, 1]."""
    import jax.numpy as jnp

    t = table.shape[0] - 1
    u = jnp.clip(cos, 0.0, 1.0) * t
    i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, t - 1)
    f = (u - i0.astype(u.dtype))[..., None]
    return table[i0] * (1 - f) + table[i0 + 1] * f


def fresnel_lowrank(n: np.ndarray, k: np.ndarray, rank: int, dtype=np.float64):
    """Iron's rank-``rank`` Fresnel basis (:func:`jkatana.light.prefilter.fresnel_basis`) in ``dtype``."""
    import jax
    import jax.numpy as jnp

    from jkatana.light.prefilter import fresnel_basis
    from jkatana.models import Conductor

    fb = fresnel_basis(Conductor(jnp.asarray(n), jnp.asarray(k)), rank=rank)
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype), fb)


def run(quick: bool) -> list[dict]:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from benchmarks._harness import record, timeit
    from jkatana.spectral import delta_e_display
    from jkatana.models import fresnel_conductor, fresnel_schlick, normal_incidence
    from jkatana.spectral import DEFAULT_GRID, WavelengthGrid, load_optical_constants, xyz_to_rgb_matrix, \
        xyz_weights

    rng = np.random.default_rng(20260122)
    n_pix = 2**17 if quick else 2**18
    n_err = min(n_pix, 2**16 if quick else 2**17)
    repeats = 5 if quick else 9
    min_time = 0.3 if quick else 1.5
    n_tex = 4096
    f32 = np.float32
    table = load_optical_constants("Fe-Johnson")

    rgb_tex = load_texels(n_tex, rng)
    cos_pix = np.cos(np.deg2rad(rng.uniform(0.0, 89.0, n_pix)))
    idx = rng.integers(0, n_tex, n_pix).astype(np.int32)
    cos_j, idx_j = jnp.asarray(cos_pix, f32), jnp.asarray(idx)
    cos_e, idx_e = cos_pix[:n_err], idx[:n_err]

    wl61 = DEFAULT_GRID.wavelengths
    W61 = xyz_weights(DEFAULT_GRID)
    n61, k61 = table.on_grid(DEFAULT_GRID)
    E61 = upsample(rgb_tex, DEFAULT_GRID)  # (tex, 61)

    def bands(grid: WavelengthGrid):
        n, k = table.on_grid(grid)
        E = upsample(rgb_tex, grid)
        W = interp_matrix(grid.wavelengths, wl61).T @ W61 if grid != DEFAULT_GRID else W61
        if grid.step < DEFAULT_GRID.step:  # finer than the reference: its own Riemann weights
            W = xyz_weights(grid)
        return n, k, E, W

    def band_fn(n, k, E, W, dtype):
        n, k, E, W = (jnp.asarray(a, dtype) for a in (n, k, E, W))

        @jax.jit
        def f(cos, i):
            return (fresnel_conductor(cos[:, None], n, k) * E[i]) @ W
        return f

    ref_fn = band_fn(n61, k61, E61, W61, np.float64)
    xyz_ref = np.asarray(ref_fn(jnp.asarray(cos_e), jnp.asarray(idx_e)))

    rows: list[dict] = []

    def measure(study, variant, fn, *, is_reference=False, note="", extra_err=None, **extra):
        t = timeit(lambda: fn(cos_j, idx_j), repeats=repeats, warmup=1, min_time=min_time)
        out = np.asarray(fn(cos_j, idx_j))[:n_err]
        err = delta_e_display(xyz_ref, out)
        err.pop("exposure"), err.pop("pixels")  # not errors
        err["xyz_rel_max"] = float(np.max(np.abs(out - xyz_ref)) / np.max(np.abs(xyz_ref)))
        err.update(extra_err or {})
        rows.append(record("bench_spectral", {"variant": variant, "pixels": n_pix}, time_s=t, error=err,
                           reference="61 bands (5 nm), exact Fresnel, float64", study=study, variant=variant,
                           error_metric="dE2000_mean", items=n_pix, tolerance=1.0,
                           is_reference=is_reference, note=note, dtype="float32", **extra))
        _log(f"{study}: {variant}: dE mean {err['dE2000_mean']:.4f} p95 {err['dE2000_p95']:.4f}, "
             f"{t['median'] / n_pix * 1e9:.2f} ns/pixel")

    # --- study: spectral sampling -------------------------------------------------------------
    S = "spectral sampling"
    measure(S, "61 bands", band_fn(n61, k61, E61, W61, f32), is_reference=True,
            note="the paper's grid in float32 (error = float32 rounding only)")
    for count in ((31, 16, 8) if quick else (301, 31, 16, 8)):
        grid = WavelengthGrid(400.0, 700.0, 1.0) if count == 301 else WavelengthGrid.with_count(400.0, 700.0, count)
        label = "301 bands (1 nm)" if count == 301 else f"{count} bands"
        note = "finer than the reference: the reference's own sampling error" if count == 301 else \
            "point samples, weights integrate the linear interpolant against the CMFs"
        measure(S, label, band_fn(*bands(grid), f32), note=note)

    # RGB renderers get each texel's RGB as the spectral texel's own colour (so that with F = 1
    # both agree exactly, and the error is the RGB rendering's alone, not the upsampling's), in
    # the upsampling's unit Y_E = Σ S ȳ Δλ / Σ ȳ Δλ (jkatana.light.upsampling).
    ysum = float(W61[:, 1].sum())
    rgb_eff = (E61 @ W61) @ xyz_to_rgb_matrix("sRGB").T / ysum
    m_rgb2xyz = np.linalg.inv(xyz_to_rgb_matrix("sRGB")) * ysum
    edges = ((400, 500), (500, 600), (600, 701))
    n_c = np.array([n61[(wl61 >= a) & (wl61 < b)].mean() for a, b in edges][::-1])  # R, G, B
    k_c = np.array([k61[(wl61 >= a) & (wl61 < b)].mean() for a, b in edges][::-1])
    measure(S, "RGB (3), per-channel n,k", band_fn(n_c, k_c, rgb_eff, m_rgb2xyz.T, f32),
            note="n, k averaged over 600–700 / 500–600 / 400–500 nm")

    cos_tab = np.linspace(0.0, 1.0, N_COS_TABLE)
    F_tab = np.asarray(fresnel_conductor(jnp.asarray(cos_tab)[:, None], jnp.asarray(n61), jnp.asarray(k61)))
    white = upsample(np.ones((1, 3)), DEFAULT_GRID)[0]  # the upsampled RGB white (D65-like)
    F_rgb = ((F_tab * white) @ W61) @ xyz_to_rgb_matrix("sRGB").T / ysum  # linear sRGB of F under that white
    F_rgb_j, rgb_j, M_j = (jnp.asarray(a, f32) for a in (F_rgb, rgb_eff, m_rgb2xyz.T))

    @jax.jit
    def rgb_table_fn(cos, i):
        return (lerp_table(F_rgb_j, cos) * rgb_j[i]) @ M_j
    measure(S, "RGB (3), tabulated F colour", rgb_table_fn, note="sRGB colour of spectral F(θ)·D65, 256 cosines")

    E61_j, n61_j, k61_j, W61_j = (jnp.asarray(a, f32) for a in (E61, n61, k61, W61))
    for rank in range(1, 6):
        fb = fresnel_lowrank(n61, k61, rank)
        t0 = time.perf_counter()
        baked = np.einsum("rl,tl,lc->trc", np.asarray(fb.basis), E61, W61)  # (tex, r, 3): XYZ of b_r E
        precompute = time.perf_counter() - t0
        fb32, baked_j = fresnel_lowrank(n61, k61, rank, f32), jnp.asarray(baked, f32)

        @jax.jit
        def lowrank_fn(cos, i, fb32=fb32, baked_j=baked_j):
            return jnp.einsum("nr,nrc->nc", fb32.coeffs(cos), baked_j[i])
        measure(S, f"rank {rank} basis", lowrank_fn, precompute_s=precompute,
                note=f"per-texel bake {precompute * 1e3:.1f} ms for {n_tex} texels, not in the time")

    # --- study: Fresnel approximation (61 bands) -----------------------------------------------
    S = "Fresnel approximation"
    cos_dense = np.cos(np.deg2rad(np.linspace(0.0, 90.0, 2001)))
    F_exact = np.asarray(fresnel_conductor(jnp.asarray(cos_dense)[:, None], jnp.asarray(n61), jnp.asarray(k61)))

    def f_err(F):
        return {"F_max_abs": float(np.max(np.abs(F - F_exact)))}

    measure(S, "exact (Born & Wolf)", band_fn(n61, k61, E61, W61, f32), is_reference=True,
            extra_err=f_err(np.asarray(fresnel_conductor(jnp.asarray(cos_dense, f32)[:, None], n61_j, k61_j))),
            note="float32; error = float32 rounding only")
    f0 = normal_incidence(n61, k61)
    f0_j = jnp.asarray(f0, f32)

    @jax.jit
    def schlick_fn(cos, i):
        return (fresnel_schlick(cos[:, None], f0_j) * E61_j[i]) @ W61_j
    measure(S, "Schlick (1994)", schlick_fn, extra_err=f_err(np.asarray(fresnel_schlick(cos_dense[:, None], f0))),
            note="F0 = exact F(0°) per band")
    for rank in range(1, 6):
        fb32 = fresnel_lowrank(n61, k61, rank, f32)

        @jax.jit
        def lr_fn(cos, i, fb32=fb32):
            return (fb32.reconstruct(cos) * E61_j[i]) @ W61_j
        F_lr = np.asarray(fresnel_lowrank(n61, k61, rank).reconstruct(jnp.asarray(cos_dense)))
        measure(S, f"rank {rank}", lr_fn, extra_err=f_err(F_lr),
                note="jkatana.light fresnel_basis (2049 angles), reconstructed per band")
    return rows

"""Spectral sampling and Fresnel approximations: error (ΔE2000) against time per pixel.

What is evaluated is the core of every shaded pixel of a polished blade: the
light of one environment texel reflected by iron at one angle,

    XYZ = Σλ F(n(λ), k(λ), θ) · E(λ) · x̄ȳz̄(λ) Δλ       (paper eqs. 1 and 6),

for a batch of pixel evaluations with random angles θ ∈ [0°, 89°] and random
texels of real environment maps (Poly Haven, CC0; ``/work/shared/data/envmaps``).
The maps are RGB, so each texel is upsampled to a spectrum with the linear
basis of Mallett & Yuksel ("Spectral Primary Decomposition for Rendering with
sRGB Reflectance", EGSR 2019; colour-science's
``MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019``) times CIE D65, whose colour is the
texel's sRGB colour. Iron: Johnson & Christy (1974).

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
  texel's RGB, as RGB renderers do;
- RGB (3), tabulated F colour: the sRGB colour of the spectral F(θ)·D65,
  tabulated over 256 values of cos θ (a careful RGB renderer);
- rank-r basis (r = 1…5): SVD of iron's F(cos θ, λ) tabulated at 256 cosines,
  F ≈ Σᵣ aᵣ(θ) bᵣ(λ); each texel's XYZ of bᵣ(λ)E(λ) is baked once (timed
  separately as ``precompute_s``), a pixel then costs r table look-ups and 3r
  multiply–adds. (jkatana.light had no basis function when this was written,
  so the SVD is done here with NumPy.)

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

ENVMAPS = ("city", "sunset", "forest", "interior")
ENV_DIR = "/work/shared/data/envmaps"
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


def upsample_basis(wavelengths: np.ndarray) -> np.ndarray:
    """Emission basis on ``wavelengths``: Mallett–Yuksel (2019) reflectance basis × D65, ``(wl, 3)``.

    Normalised so that RGB (1, 1, 1) has luminance Y = 1 on the 61-band grid.
    """
    import colour

    from jkatana.spectral import DEFAULT_GRID, xyz_weights

    b = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    d65 = colour.SDS_ILLUMINANTS["D65"]

    def on(wl):
        basis = np.stack([np.interp(wl, b.wavelengths, b.values[:, i]) for i in range(3)], axis=-1)
        return basis * np.interp(wl, d65.wavelengths, d65.values)[:, None]

    white = on(DEFAULT_GRID.wavelengths).sum(axis=1) @ xyz_weights(DEFAULT_GRID)[:, 1]
    return on(np.asarray(wavelengths, np.float64)) / white


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


def fresnel_lowrank(n: np.ndarray, k: np.ndarray, rank: int, count: int = N_COS_TABLE):
    """SVD of F(cos θ, λ) at ``count`` uniform cosines: ``(a: (count, r), b: (r, wl))``."""
    import jax.numpy as jnp

    from jkatana.models import fresnel_conductor

    cos = np.linspace(0.0, 1.0, count)
    F = np.asarray(fresnel_conductor(jnp.asarray(cos)[:, None], jnp.asarray(n), jnp.asarray(k)))
    u, s, vt = np.linalg.svd(F, full_matrices=False)
    return u[:, :rank] * s[:rank], vt[:rank]


def run(quick: bool) -> list[dict]:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from benchmarks._harness import delta_e_display, record, timeit
    from jkatana.models import fresnel_conductor, fresnel_schlick, normal_incidence
    from jkatana.spectral import DEFAULT_GRID, WavelengthGrid, load_optical_constants, xyz_to_rgb_matrix, \
        xyz_weights

    rng = np.random.default_rng(20260122)
    n_pix = 2**17 if quick else 2**19
    n_err = min(n_pix, 2**16 if quick else 2**17)
    repeats = 5 if quick else 9
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
    E61 = rgb_tex @ upsample_basis(wl61).T  # (tex, 61)

    def bands(grid: WavelengthGrid):
        n, k = table.on_grid(grid)
        E = rgb_tex @ upsample_basis(grid.wavelengths).T
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
        t = timeit(lambda: fn(cos_j, idx_j), repeats=repeats, warmup=1)
        out = np.asarray(fn(cos_j, idx_j))[:n_err]
        err = delta_e_display(xyz_ref, out)
        err.pop("exposure")
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

    m_rgb2xyz = np.linalg.inv(xyz_to_rgb_matrix("sRGB"))
    edges = ((400, 500), (500, 600), (600, 701))
    n_c = np.array([n61[(wl61 >= a) & (wl61 < b)].mean() for a, b in edges][::-1])  # R, G, B
    k_c = np.array([k61[(wl61 >= a) & (wl61 < b)].mean() for a, b in edges][::-1])
    measure(S, "RGB (3), per-channel n,k", band_fn(n_c, k_c, rgb_tex, m_rgb2xyz.T, f32),
            note="n, k averaged over 600–700 / 500–600 / 400–500 nm")

    cos_tab = np.linspace(0.0, 1.0, N_COS_TABLE)
    F_tab = np.asarray(fresnel_conductor(jnp.asarray(cos_tab)[:, None], jnp.asarray(n61), jnp.asarray(k61)))
    d65 = upsample_basis(wl61).sum(axis=1)
    F_rgb = ((F_tab * d65) @ W61) @ xyz_to_rgb_matrix("sRGB").T  # linear sRGB of F under (normalised) D65
    F_rgb_j, rgb_j, M_j = (jnp.asarray(a, f32) for a in (F_rgb, rgb_tex, m_rgb2xyz.T))

    @jax.jit
    def rgb_table_fn(cos, i):
        return (lerp_table(F_rgb_j, cos) * rgb_j[i]) @ M_j
    measure(S, "RGB (3), tabulated F colour", rgb_table_fn, note="sRGB colour of spectral F(θ)·D65, 256 cosines")

    E61_j, n61_j, k61_j, W61_j = (jnp.asarray(a, f32) for a in (E61, n61, k61, W61))
    for rank in range(1, 6):
        a, b = fresnel_lowrank(n61, k61, rank)
        t0 = time.perf_counter()
        baked = np.einsum("rl,tl,lc->trc", b, E61, W61)  # (tex, r, 3): XYZ of b_r(λ) E(λ) per texel
        precompute = time.perf_counter() - t0
        a_j, baked_j = jnp.asarray(a, f32), jnp.asarray(baked, f32)

        @jax.jit
        def lowrank_fn(cos, i, a_j=a_j, baked_j=baked_j):
            return jnp.einsum("nr,nrc->nc", lerp_table(a_j, cos), baked_j[i])
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
        a, b = fresnel_lowrank(n61, k61, rank)
        a_j, b_j = jnp.asarray(a, f32), jnp.asarray(b, f32)

        @jax.jit
        def lr_fn(cos, i, a_j=a_j, b_j=b_j):
            return ((lerp_table(a_j, cos) @ b_j) * E61_j[i]) @ W61_j
        F_lr = np.asarray(lerp_table(jnp.asarray(a), jnp.asarray(cos_dense))) @ b
        measure(S, f"rank {rank}", lr_fn, extra_err=f_err(F_lr),
                note=f"F tabulated at {N_COS_TABLE} cosines, reconstructed per band")
    return rows

"""Where the GGX remainder's light goes: per μ level and cos θv, the lobe kernel's energy (taps.polar_lobe_kernel:
the whole lobe out to 48 μ, normalised to 1) against the fitted taps' kernel, in rings of angle from R (in μ).
'3 taps': the three-tap table of taps.tap_fit (what the shader read before); 'tail': taps.tail_fit's three taps
and tail tap (tables.cached_tail_fit). Lobes: the sun-glint test's GGX hiraji α 0.05 and Beckmann hamon α 0.12
families (lobe_shape keys, α = μ), levels MU_LEVELS[2:9]. Run: python energy.py [tail]."""
import sys, numpy as np, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from jkatana.interactive import levels as LV, taps as T, tables as TB
from jkatana.interactive.lobe_tables import region_lobes
from jkatana.models import Conductor
from jkatana.models.lobes import lobe_shape
from jkatana.spectral import DEFAULT_GRID
from jkatana.fit._model import FIT_MODELS
cond = Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float64)
def key(model, values):
    fm = FIT_MODELS[model]
    return lobe_shape(fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params())[1]
lobes = region_lobes({"hiraji": key("ggx", {"scale": 2000.0, "alpha": 0.05}),
                      "hamon": key("beckmann", {"scale": 2000.0, "alpha": 0.12})})
mus = LV.MU_LEVELS[2:9]
taps3, _, _ = TB.cached_tap_fit(cond, mus, 64, None, lobes)
with_tail = "tail" in sys.argv[1:]
if with_tail:
    taps_t, tail, l1t = TB.cached_tail_fit(cond, mus, 64, None, lobes)
cos = np.linspace(0, 1, 64)
edges = np.array([0, 1, 2, 4, 8, 16, 48])
print("rings of angle from R, in μ:", list(zip(edges[:-1], edges[1:])))
for m, fam in enumerate(lobes):
    print("== region", m, fam.name)
    for k, mu in enumerate(mus):
        for ci in (63, 48, 32, 20):
            K, ap, aq, dw, psi = T.polar_lobe_kernel(fam(jnp.asarray(mu)), cond, max(cos[ci], 1e-3), 64, 48, width=mu)
            K, dw, psi = np.asarray(K), np.asarray(dw), np.asarray(psi)
            ring = np.clip(np.searchsorted(edges[1:-1], psi / mu, side="right"), 0, len(edges) - 2)
            def rings(F):
                return np.bincount(ring.ravel(), (F * dw).ravel(), minlength=len(edges) - 1)
            t = taps3[m, k, ci]
            p3 = np.concatenate([t[:4], np.log(np.maximum(t[4:], 1e-300))])
            F3 = np.asarray(T.tap_kernel(jnp.asarray(p3), mu, ap, aq, mus[0]))
            line = (f"mu {mu:.4f} cos {cos[ci]:.2f} | lobe " + " ".join(f"{x:.3f}" for x in rings(K))
                    + " | 3 taps " + " ".join(f"{x:.3f}" for x in rings(F3)) + f" L1 {np.sum(np.abs(F3 - K) * dw):.3f}")
            if with_tail:
                t, tl = taps_t[m, k, ci], tail[m, k, ci]
                p = np.concatenate([t[:4], tl[:2], np.log(np.maximum(np.r_[t[4:] * (1 - tl[2]), tl[2]], 1e-300))])
                Ft = np.asarray(T.tail_kernel(jnp.asarray(p), mu, ap, aq, mus[0], mus[-1]))
                line += (" | tail " + " ".join(f"{x:.3f}" for x in rings(Ft)) + f" L1 {np.sum(np.abs(Ft - K) * dw):.3f}"
                         + f" (w_t {tl[2]:.3f}, μ_t/μ {np.exp(tl[0]):.2f})")
            print(line, flush=True)

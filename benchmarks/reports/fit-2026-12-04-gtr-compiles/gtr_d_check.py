"""GTR's D in float32 and float64 against a long-double reference (numpy longdouble, 64-bit mantissa) over
α = 1e-6…1, γ = 1…4, φ from the peak to cos φ → 0, and at (tan φ, cos φ) pairs near the dtype's limits; its
gradient in (α, γ, tan φ, cos φ) finite. Run with a checkout's python (from
its root): ``python gtr_d_check.py``; prints the worst relative error per dtype, and counts of non-finite
values and gradients. Run on the base and the branch for the comparison."""
import itertools

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
from jkatana.models.lobes import GTR  # noqa: E402

alphas = [1e-6, 1e-4, 1e-2, 0.1, 0.5, 1.0]
gammas = [1.0, 1.2, 1.5, 2.0, 3.0, 4.0]
phis = np.concatenate([[0.0], np.geomspace(1e-9, 1e-1, 17), np.linspace(0.2, np.pi / 2 - 1e-3, 12),
                       np.pi / 2 - np.geomspace(1e-4, 1e-7, 4)])


def ref(a, g, phi):
    """D in long double at angles ``phi``, from the bracket α² cos²φ + sin²φ."""
    L = np.longdouble
    a, g, phi = L(a), L(g), np.asarray(phi, L)
    a2 = a * a
    if a == 1:
        c = 1 / L(np.pi)
    elif g == 1:
        c = (a2 - 1) / (L(np.pi) * np.log(a2))
    else:
        c = (g - 1) * (a2 - 1) / (L(np.pi) * (1 - a2 ** (1 - g)))
    return np.asarray(c / (a2 * np.cos(phi) ** 2 + np.sin(phi) ** 2) ** g, np.float64)


for dtype in (jnp.float64, jnp.float32):
    worst, bad_v, bad_g, n = 0.0, 0, 0, 0
    for a, g in itertools.product(alphas, gammas):
        ph = phis.astype(dtype)  # the angle as the dtype holds it; reference at that angle
        t, c = jnp.tan(jnp.asarray(ph)), jnp.cos(jnp.asarray(ph))
        d = np.asarray(GTR(jnp.asarray(a, dtype), jnp.asarray(g, dtype)).D_tan(t, c), np.float64)
        r = ref(a, g, np.asarray(ph, np.float64))
        ok = np.isfinite(d)
        bad_v += int((~ok).sum())
        rel = np.abs(d - r) / r
        worst = max(worst, float(np.max(np.where(ok, rel, 0.0))))
        f = lambda aa, gg, tt, cc: jnp.sum(jnp.log(GTR(aa, gg).D_tan(tt, cc)))  # noqa: E731
        gr = jax.grad(f, argnums=(0, 1, 2, 3))(jnp.asarray(a, dtype), jnp.asarray(g, dtype), t, c)
        bad_g += sum(int((~np.isfinite(np.asarray(x))).sum()) for x in gr)
        n += ph.size
    print(f"{jnp.dtype(dtype).name}: {n} points, worst relative error vs long double {worst:.3g}, "
          f"non-finite D {bad_v}, non-finite gradient entries {bad_g}")

for dtype, (tt, cc) in ((jnp.float32, (1e30, 1e-30)), (jnp.float32, (1e18, 1e-18)), (jnp.float64, (1e300, 1e-300)),
                        (jnp.float64, (1e150, 1e-150))):
    for a, g in itertools.product(alphas, gammas):
        t, c = jnp.asarray([tt, 0.0], dtype), jnp.asarray([cc, 0.0], dtype)
        d = np.asarray(GTR(jnp.asarray(a, dtype), jnp.asarray(g, dtype)).D_tan(t, c))
        gr = jax.grad(lambda aa, gg, t_, c_: jnp.sum(GTR(aa, gg).D_tan(t_, c_)), argnums=(0, 1, 2, 3))(
            jnp.asarray(a, dtype), jnp.asarray(g, dtype), t, c)
        if not (np.all(np.isfinite(d)) and all(np.all(np.isfinite(np.asarray(x))) for x in gr)):
            print(f"non-finite at {jnp.dtype(dtype).name} tan {tt:g} cos {cc:g} alpha {a:g} gamma {g:g}: D {d}")
print("limits checked")

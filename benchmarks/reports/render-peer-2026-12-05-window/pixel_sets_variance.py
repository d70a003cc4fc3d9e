"""Pixel estimates' variance, window on/off, pixel sets or independent shifts, on tests/test_render_pixel_sets.py's scene
(a sky with its sun in the map, narrow lobes, 4 samples), relative to the whole map with independent shifts.
Run from the repository root: ``PYTHONPATH=. python benchmarks/reports/render-peer-2026-12-05-window/pixel_sets_variance.py``."""
import sys; sys.path.insert(0, "tests")
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import test_render_pixel_sets as t
from jkatana.render.shading import Plan
rng = np.random.default_rng(3)
n_pix, N, seeds = 6, 4, 256
mat, env, px = t._scene(n_pix, rng)
ids = t._ids(n_pix)
keys = jax.random.split(jax.random.PRNGKey(11), seeds)
pix = lambda a: a.reshape(a.shape[:-1] + (n_pix, t.S)).mean(-1)
res = {}
for name, plan, i in [("sets+win", Plan(samples=N, subpixels=t.S, fresnel_rank=0, env_window=2.0), ids),
                      ("indep+win", Plan(samples=N, fresnel_rank=0, env_window=2.0), None),
                      ("sets", Plan(samples=N, subpixels=t.S, fresnel_rank=0, env_window=None), ids),
                      ("indep", Plan(samples=N, fresnel_rank=0, env_window=None), None)]:
    a = np.asarray(t._shader(plan, mat, env, px, i)(keys))[..., 1]
    res[name] = pix(a).var(0, ddof=1)
for k in res: print(k, np.round(res[k] / res["indep"], 3))

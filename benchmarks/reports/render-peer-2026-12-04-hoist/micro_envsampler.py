import os, sys, time, numpy as np
sys.path.insert(0, "benchmarks/reports/render-peer-2026-12-04-hoist")
import prof, jax, jax.numpy as jnp
from jkatana.light.sampling import _row_search
b = prof.capture()
s = b["env"].sampler
n = b["px"].normal.shape[0]
rng = np.random.default_rng(0)
u = jnp.asarray(rng.uniform(0, 1, (n, 2)), jnp.float32)
def t(f, *a, reps=7):
    f = jax.jit(f); jax.block_until_ready(f(*a)); out=[]
    for _ in range(reps):
        c0=time.process_time(); jax.block_until_ready(f(*a)); out.append(time.process_time()-c0)
    return np.median(out)/n*1e9
print("sample_uniform2", t(lambda u: s.sample_uniform2(u), u))
print("marginal searchsorted", t(lambda x: jnp.searchsorted(s.marginal, x, side="right"), u[:,0]))
for m in ("scan", "scan_unrolled", "sort", "compare_all"):
    print("  method", m, t(lambda x, m=m: jnp.searchsorted(s.marginal, x, side="right", method=m), u[:,0]))
j = jnp.clip(jnp.searchsorted(s.marginal, u[:,0], side="right") - 1, 0, 127)
print("row search", t(lambda j, x: _row_search(s.conditional, j, x), j, u[:,1]))
i = _row_search(s.conditional, j, u[:,1])
print("one 2D gather", t(lambda j, i: s.conditional[j, i], j, i))
print("flat gather", t(lambda j, i: s.conditional.reshape(-1)[j * 257 + i], j, i))
print("texel pdf gather", t(lambda j, i: s.texel_pdf[j, i], j, i))

"""GTR's D alone, compiled: process CPU per call of D and of its forward-mode derivative in (log α, logit γ) on
1188 points × 64 copies (the paper protocol's directions; α = 0.05, γ = 1.5). Run from a checkout with PYTHONPATH
set to it, alternated between base and branch: ``REPEATS=2000 python gtr_d_micro.py``."""
import os
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jkatana.brdf.geometry import goniometer_vectors  # noqa: E402
from jkatana.measure.protocol import Protocol, as_pairs  # noqa: E402
from jkatana.models.lobes import GTR, Geometry  # noqa: E402

reps = int(os.environ.get("REPEATS", 2000))
pairs = np.asarray(as_pairs(Protocol()), np.float64)
L, V = goniometer_vectors(pairs[:, 0], pairs[:, 1])
g = Geometry.of(jnp.asarray(np.tile(L, (64, 1))), jnp.asarray(np.tile(V, (64, 1))))


def d(q):
    return GTR(jnp.exp(q[0]), 1.0 + 3.0 * jax.nn.sigmoid(q[1])).D_tan(g.tan_phi, g.cos_phi)


q = jnp.asarray([np.log(0.05), np.log(0.5 / 2.5)])
val, jac = jax.jit(d), jax.jit(jax.jacfwd(d))
for name, f in (("D", val), ("dD/dq", jac)):
    jax.block_until_ready(f(q))
    c0 = time.process_time()
    for _ in range(reps):
        jax.block_until_ready(f(q))
    print(f"{name:6s} cpu/call {(time.process_time() - c0) / reps * 1e6:8.1f} us  ({g.cos_phi.size} points, "
          f"load {os.getloadavg()[0]:.2f})", flush=True)

"""Per-sample CPU cost of the environment samplers, isolated (jitted scan of 8 × 32768 samples): the whole map
(``sample_uniform2``), the window (``window`` + ``sample_window``), the window alone, and the two densities.
Run from the repository root with ``PYTHONPATH=.`` (Mitsuba installed: the map is Mitsuba's spectral envmap)."""
import os, time, tempfile
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import jax, jax.numpy as jnp, numpy as np
from jkatana.light.envmap import EnvMap
from jkatana.light.sampling import EnvSampler
from jkatana.spectral.grid import WavelengthGrid
from jkatana.shared import shared_data
from validation import mitsuba as mc
grid = WavelengthGrid(360.0, 830.0, 5.0)
with tempfile.TemporaryDirectory() as d:
    p = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
    rad = mc.mitsuba_env_spectra(p, grid, nodes=None)
s = EnvSampler.build(EnvMap(jnp.asarray(rad, jnp.float32), grid), bilinear="max")
P = 16384*2
key = jax.random.PRNGKey(0)
u = jax.random.uniform(key, (8, P, 2))
dirs = jax.random.normal(jax.random.PRNGKey(1), (P, 3)); dirs = dirs/jnp.linalg.norm(dirs, axis=-1, keepdims=True)
half = jnp.full((P,), 0.76)
def full(u, dirs):
    def body(acc, uk):
        d, p, a, b = s.sample_uniform2(uk)
        return acc + d[:, 0]*p + a + b, None
    return jax.lax.scan(body, jnp.zeros(P), u)[0]
def win(u, dirs):
    w = s.window(dirs, half)
    def body(acc, uk):
        d, p, a, b = s.sample_window(w, uk)
        return acc + d[:, 0]*p + a + b, None
    return jax.lax.scan(body, jnp.zeros(P), u)[0]
def winonly(u, dirs):
    w = s.window(dirs, half)
    return w[4] + w[0]
def pdfw(u, dirs):
    w = s.window(dirs, half)
    def body(acc, uk):
        return acc + s.pdf_window(w, uk[:, 0], uk[:, 1]), None
    return jax.lax.scan(body, jnp.zeros(P), u)[0]
def pdff(u, dirs):
    def body(acc, uk):
        return acc + s.pdf_uv(uk[:, 0], uk[:, 1]), None
    return jax.lax.scan(body, jnp.zeros(P), u)[0]
for name, f in [("full", full), ("win", win), ("winonly", winonly), ("pdfw", pdfw), ("pdff", pdff)]:
    jf = jax.jit(f); jf(u, dirs).block_until_ready()
    ts=[]
    for _ in range(5):
        c0=time.process_time(); jf(u, dirs).block_until_ready(); ts.append(time.process_time()-c0)
    print(f"{name}: {min(ts)/(8*P)*1e9:.1f} ns CPU per sample")

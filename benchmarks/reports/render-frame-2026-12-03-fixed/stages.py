"""Per-stage CPU of the 1-spp study frame: each stage run alone with block_until_ready (fresh env per frame)."""
import os, sys, time, tempfile, dataclasses
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import numpy as np, jax, jax.numpy as jnp
import jkatana.render.frame as fm
from jkatana.shared import shared_data
from validation import mitsuba as mc
box = {}
orig = fm.render_frame
def grab(plan, mat, env, lights, geometry, cam, maps, cmf, **k):
    box.update(plan=plan, mat=mat, env=env, cam=cam, maps=maps, cmf=cmf, k=k)
    return orig(plan, mat, env, lights, geometry, cam, maps, cmf, **k)
fm.render_frame = grab
spp = int(sys.argv[1]) if len(sys.argv) > 1 else 1
with tempfile.TemporaryDirectory() as d:
    envp = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
    def T(label, f, n=5):
        ts = []
        for i in range(n + 1):
            mc.render_jkatana(envp, alpha=0.2, size=256, samples=spp, supersample=2, seed=1, env_nodes=None)
            c = time.process_time(); jax.block_until_ready(f()); ts.append(time.process_time() - c)
        print(f"{label:40s} CPU {np.median(ts[1:]):.4f}", flush=True)
    b = lambda: box
    T("whole render_frame", lambda: orig(box['plan'], box['mat'], box['env'], None, ("sphere", (0.0, 0.0, 0.0), 1.0), box['cam'], box['maps'], box['cmf'], **box['k']).xyz)
    T("background_camera", lambda: fm.background_camera(box['env'], box['cam'], box['cmf'], jnp.float32))
    T("gbuffer", lambda: fm.gbuffer(("sphere", (0.0, 0.0, 0.0), 1.0), box['cam']).index)
    def px():
        gb = fm.gbuffer(("sphere", (0.0, 0.0, 0.0), 1.0), box['cam'])
        uv = jnp.asarray(gb.hit_uv, jnp.float32); mp = fm._sample_map(jnp.asarray(box['maps'], jnp.float32), uv)
        return fm.Pixels(jnp.asarray(gb.hit_position, jnp.float32), jnp.asarray(gb.hit_normal, jnp.float32), jnp.asarray(gb.hit_view, jnp.float32), mp[:, 0], mp[:, 1], mp[:, 2])
    T("pixels upload + map", px)
    def fold():
        plan = fm.resolve_plan(box['plan'], box['mat'])
        from jkatana.render.shading import fresnel_rank_for
        _, vt = fresnel_rank_for(box['mat'].ftable, _basis_too=True)
        return fm.folded(plan.fresnel_rank, box['mat'], box['env'], jnp.asarray(box['cmf'], jnp.float32), jnp.asarray(vt[:plan.fresnel_rank], jnp.float32))
    T("resolve + fold", fold)
    def sp():
        gb = fm.gbuffer(("sphere", (0.0, 0.0, 0.0), 1.0), box['cam']); P = px(); W = 512; ss = 2
        row, col = np.divmod(gb.index, W)
        ids = fm.PixelIds(((row // ss) * (W // ss) + col // ss).astype(np.uint32), ((row % ss) * ss + col % ss).astype(np.int32))
        plan = dataclasses.replace(box['plan'], subpixels=4)
        return fm.shade_pixels(plan, box['mat'], box['env'], None, P, box['cmf'], jax.random.PRNGKey(1), ids=ids)[0]
    T("pixels + shade_pixels", sp)
    from jax.sharding import NamedSharding, PartitionSpec as PS
    pre = {}
    def prep():
        gb = fm.gbuffer(("sphere", (0.0, 0.0, 0.0), 1.0), box['cam']); P = px(); W = 512; ss = 2
        row, col = np.divmod(gb.index, W)
        ids = fm.PixelIds(((row // ss) * (W // ss) + col // ss).astype(np.uint32), ((row % ss) * ss + col % ss).astype(np.int32))
        plan = fm.resolve_plan(dataclasses.replace(box['plan'], subpixels=4), box['mat'])
        from jkatana.render.shading import fresnel_rank_for
        _, vt = fresnel_rank_for(box['mat'].ftable, _basis_too=True)
        mat, env = fm.folded(plan.fresnel_rank, box['mat'], box['env'], jnp.asarray(box['cmf'], jnp.float32), jnp.asarray(vt[:plan.fresnel_rank], jnp.float32))
        chunk, sizes = fm._call_sizes(plan, P.normal.shape[0], 2, 16384)
        calls = fm._split_calls(P, tuple(2 * s for s in sizes))
        f, mesh = fm._compiled(plan, 2, chunk)
        rep, split = NamedSharding(mesh, PS()), NamedSharding(mesh, PS("d"))
        mat, env, cmf = jax.device_put((mat, env, jnp.asarray(box['cmf'], jnp.float32)), rep)
        pad = sum(sizes) * 2 - P.normal.shape[0]
        pid = np.concatenate([ids.pixel, np.zeros(pad, np.uint32)]); sid = np.concatenate([ids.subpixel, np.zeros(pad, np.int32)])
        args = []
        for i, s in enumerate(sizes):
            sl = slice(i * 2 * chunk, i * 2 * chunk + 2 * s)
            args.append((jax.device_put(calls[i], split), jax.device_put(fm.PixelIds(pid[sl], sid[sl]), split)))
        key = jax.device_put(jax.random.PRNGKey(1), rep)
        pre.update(f=f, mat=mat, env=env, cmf=cmf, args=args, key=key)
        return [a[0].normal for a in args]
    T("prep (all but the shading calls)", prep)
    def calls():
        prep()
        c = time.process_time()
        out = [pre['f'](pre['mat'], pre['env'], None, a, None, pre['cmf'], pre['key'], i) for a, i in pre['args']]
        jax.block_until_ready(out); pre['t'] = time.process_time() - c
        return out
    ts = []
    for i in range(6):
        calls(); ts.append(pre['t'])
    print("shading calls only, CPU", np.median(ts[1:]), "sizes", fm._call_sizes(fm.resolve_plan(box['plan'], box['mat']), 186104, 2, 16384))

"""Mitsuba 3 alone in a process that never imports JAX: three 64-spp calls (multijitter + direct, 256²) on an
environment file written beforehand by validation.mitsuba.small_envmap. Argument: that file. DRJIT_LIBLLVM_PATH
chooses the LLVM that Dr.Jit loads (mitsuba_llvm.log)."""
import os, sys, time
sys.path.insert(0, os.getcwd())
from validation import mitsuba as mc
env = sys.argv[1]
variant = mc.mitsuba_variant()
for spp in (64, 64, 64):
    t0, c0 = time.perf_counter(), time.process_time()
    mc.render_mitsuba(env, alpha=0.2, size=256, spp=spp, variant=variant, seed=2, sampler="multijitter", integrator="direct")
    print(spp, "wall %.3f cpu %.3f" % (time.perf_counter() - t0, time.process_time() - c0), "jax imported:", "jax" in sys.modules, "jaxlib" in sys.modules, flush=True)

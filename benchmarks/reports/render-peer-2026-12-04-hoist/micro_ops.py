import os, time
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
import numpy as np, jax, jax.numpy as jnp
n = 186104
rng = np.random.default_rng(0)
def t(f, *a, reps=7):
    f = jax.jit(f); jax.block_until_ready(f(*a)); out=[]
    for _ in range(reps):
        c0=time.process_time(); jax.block_until_ready(f(*a)); out.append(time.process_time()-c0)
    return np.median(out)/n*1e9
d = rng.normal(size=(n,3)); d/= np.linalg.norm(d,axis=1,keepdims=True); d=jnp.asarray(d,jnp.float32)
R = jnp.asarray(np.linalg.qr(rng.normal(size=(3,3)))[0], jnp.float32)
x,y,z = d[:,0],d[:,1],d[:,2]
print("atan2", t(lambda x,z: jnp.arctan2(x,-z), x, z))
print("atan", t(lambda x: jnp.arctan(x), x))
print("acos", t(lambda x: jnp.arccos(x), x))
print("sqrt", t(lambda x: jnp.sqrt(jnp.abs(x)), x))
print("exp", t(lambda x: jnp.exp(x), x))
print("erf", t(lambda x: jax.scipy.special.erf(x), x))
print("erfinv", t(lambda x: jax.scipy.special.erfinv(x*0.99), x))
print("log", t(lambda x: jnp.log(jnp.abs(x)), x))
print("sin,cos", t(lambda x: jnp.sin(x)+jnp.cos(x), x))
print("matmul d@R.T", t(lambda d: d@R.T, d))
print("bcast rot", t(lambda d: d[:,0:1]*R[:,0]+d[:,1:2]*R[:,1]+d[:,2:3]*R[:,2], d))
from jkatana.light.envmap import direction_to_uv
print("direction_to_uv", t(lambda d: direction_to_uv(d), d))
print("dir_to_uv after matmul", t(lambda d: direction_to_uv(d@R.T), d))
from jkatana.models.geometry import to_local, tangent_frame
tt,bb = tangent_frame(d)
print("to_local stack", t(lambda v,a,b,c: to_local(v,a,b,c), d, tt,bb,d))
from jkatana.models.lobes import _vec3
print("to_local vec3", t(lambda v,a,b,c: _vec3(jnp.sum(v*a,-1),jnp.sum(v*b,-1),jnp.sum(v*c,-1)), d, tt,bb,d))

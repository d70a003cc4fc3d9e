"""The sphere G-buffer of this branch against the base tree's (BASE, a worktree of b384fb0): identical arrays on three
views, and CPU s per call (median of 7): the base, this branch without its per-view cache, with it."""
import os, sys, time, numpy as np
import importlib
from jkatana.render.camera import Camera
import jkatana.render.gbuffer as new
spec = importlib.util.spec_from_file_location('oldgb', os.environ.get('BASE', '/tmp/base-d') + '/jkatana/render/gbuffer.py'); old = importlib.util.module_from_spec(spec); sys.modules['oldgb'] = old; spec.loader.exec_module(old)
for cam, c, r in [(Camera((0,0.3,3.2),(0,0,0),fov_deg=38,width=512,height=512),(0,0,0),1.0),
                  (Camera((0.4,1.3,2.2),(0.1,0,0),fov_deg=50,width=320,height=200),(0.1,0.2,-0.3),0.7),
                  (Camera((0,0,0.5),(0,0,0),fov_deg=90,width=64,height=48),(0,0,0),1.0)]:
    a = old.gbuffer_sphere(cam, c, r); b = new.gbuffer_sphere(cam, c, r)
    for k in ("mask","index","hit_position","hit_normal","hit_tangent","hit_uv","hit_view","ray"):
        x, y = getattr(a,k), getattr(b,k)
        assert x.shape == y.shape and np.array_equal(x, y), k
    print("identical", a.index.size)
cam = Camera((0,0.3,3.2),(0,0,0),fov_deg=38,width=512,height=512)
for f,name in ((old.gbuffer_sphere,'old'),(new._sphere_hits.__wrapped__,'new uncached'),(new.gbuffer_sphere,'new cached')):
    ts=[]
    for i in range(7):
        t=time.process_time(); f(cam,(0.0,0.0,0.0),1.0); ts.append(time.process_time()-t)
    print(name, np.median(ts))

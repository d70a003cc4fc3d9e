import os, sys, numpy as np
sys.path.insert(0, "benchmarks/reports/render-peer-2026-12-04-hoist")
import prof
b = prof.capture()
s = b["env"].sampler
cond = np.asarray(s.conditional, np.float64); marg = np.asarray(s.marginal, np.float64)
H, W1 = cond.shape; W = W1 - 1
def width(cdf, G):
    # bucket k covers u in [k/G, (k+1)/G); texel index i(u) = largest i with cdf[i] <= u, clipped
    ks = np.arange(G + 1) / G
    idx = np.clip(np.searchsorted(cdf, ks, side="right") - 1, 0, len(cdf) - 2)
    return (idx[1:] - idx[:-1]).max()
for G in (W // 2, W, 2 * W, 4 * W):
    B = max(width(cond[j], G) for j in range(H))
    print("cond G", G, "max bracket", B)
for G in (H // 2, H, 2 * H, 4 * H):
    print("marg G", G, "max bracket", width(marg, G))

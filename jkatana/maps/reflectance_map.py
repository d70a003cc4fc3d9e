"""Reflectance maps: where the blade is mirror (hiraji) and where it scatters (hamon).

A map stores, per pixel of the blade's UV domain, the blend weight ``w`` of the
paper's eq. (5) and the parameters of both models (Mochizuki et al., "A
Rendering Method for Japanese Swords Based on Measured Data"):

    C(λ, x) = w(x) · C_hiraji(λ; χ(x), μ0(x)) + (1 − w(x)) · C_hamon(λ; β(x), μ1(x))

``w = 1`` is the mirror-like hiraji (Fresnel model, eq. 1), ``w = 0`` the rough
hamon (Torrance–Sparrow, eq. 2). The paper's fitted values (χ = 79000,
μ0 = 0.05 rad, β = 43000, μ1 = 0.05 rad) are :data:`PAPER_PARAMETERS`; the
built-in :func:`default_map` keeps χ, μ0 and β but widens the hamon's μ1
(see its docstring).

## Layout

Channels :data:`REFLECTANCE_CHANNELS` = ``("w", "mu0", "chi", "mu1", "beta")``,
each an ``(H, W)`` float32 array. **Row 0 is v = 0 (the mune), column 0 is
u = 0 (the machi)**, with pixel centres at ``(i + 0.5) / H`` and ``(j + 0.5) / W``:
the same (u, v) as :func:`jkatana.shape.katana.build_blade`'s UVs. On disk a map
is one multi-channel OpenEXR (:mod:`jkatana.io.exr`) with those channel names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jkatana.errors import InputError
from jkatana.io.exr import read_exr, write_exr

REFLECTANCE_CHANNELS: tuple[str, ...] = ("w", "mu0", "chi", "mu1", "beta")

#: The paper's fitted parameters (Mochizuki et al., §6.1): hiraji χ, μ0; hamon β, μ1.
PAPER_PARAMETERS: dict[str, float] = {"chi": 79000.0, "mu0": 0.05, "beta": 43000.0, "mu1": 0.05}

_KIND = "jkatana.reflectance_map"


@dataclass
class ReflectanceMap:
    """Per-pixel blend weight and model parameters over the blade's UV domain.

    **Fields:** `w`, `mu0`, `chi`, `mu1`, `beta`: ``(H, W)`` float32 arrays
    (row 0 = v = 0 at the mune, column 0 = u = 0 at the machi); `meta`: free
    provenance (strings/numbers), written to the EXR header.
    """

    w: np.ndarray
    mu0: np.ndarray
    chi: np.ndarray
    mu1: np.ndarray
    beta: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        for name in REFLECTANCE_CHANNELS:
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float32))
        self.validate()

    def validate(self, path: str | Path | None = None) -> "ReflectanceMap":
        """Check shapes and ranges; :class:`InputError` names the channel (and file)."""
        shape = self.w.shape
        for name in REFLECTANCE_CHANNELS:
            a = getattr(self, name)
            if a.ndim != 2 or a.shape != shape or a.size == 0:
                raise InputError(f"must be a non-empty (H, W) array shaped like w {shape}, got {a.shape}",
                                 path=path, field=name)
            if not np.all(np.isfinite(a)):
                raise InputError(f"has {int(np.sum(~np.isfinite(a)))} non-finite pixels",
                                 path=path, field=name)
        if self.w.min() < 0 or self.w.max() > 1:
            raise InputError(f"must lie in [0, 1], got [{self.w.min():g}, {self.w.max():g}]",
                             path=path, field="w")
        for name in ("mu0", "chi", "mu1", "beta"):
            if getattr(self, name).min() <= 0:
                raise InputError("must be positive everywhere", path=path, field=name)
        return self

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``: rows across the blade (v), columns along it (u)."""
        return self.w.shape

    def channels(self) -> dict[str, np.ndarray]:
        """``{name: (H, W)}`` in :data:`REFLECTANCE_CHANNELS` order."""
        return {name: getattr(self, name) for name in REFLECTANCE_CHANNELS}

    def write(self, path: str | Path) -> Path:
        """Write a multi-channel EXR (float32, zip), atomically."""
        header = {"jkatana_kind": _KIND, "uv_layout": "row0=v0(mune) col0=u0(machi) pixel centres"}
        header.update({f"jkatana_{k}": v for k, v in self.meta.items()})
        return write_exr(path, self.channels(), header=header)

    def sample(self, u: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray]:
        """Bilinear lookup at UV coordinates (clamped to the domain), one array per channel."""
        H, W = self.shape
        x = np.clip(np.asarray(u, np.float64) * W - 0.5, 0, W - 1)
        y = np.clip(np.asarray(v, np.float64) * H - 0.5, 0, H - 1)
        x0 = np.minimum(np.floor(x).astype(int), W - 2) if W > 1 else np.zeros_like(x, int)
        y0 = np.minimum(np.floor(y).astype(int), H - 2) if H > 1 else np.zeros_like(y, int)
        fx, fy = (x - x0) if W > 1 else 0 * x, (y - y0) if H > 1 else 0 * y
        x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
        out = {}
        for name, a in self.channels().items():
            top = a[y0, x0] * (1 - fx) + a[y0, x1] * fx
            bot = a[y1, x0] * (1 - fx) + a[y1, x1] * fx
            out[name] = (top * (1 - fy) + bot * fy).astype(np.float32)
        return out

    @classmethod
    def uniform(cls, resolution: tuple[int, int] = (4, 4), w: float = 1.0,
                **params: float) -> "ReflectanceMap":
        """A constant map (paper parameters unless given)."""
        p = {**PAPER_PARAMETERS, **params}
        full = lambda x: np.full(resolution, x, np.float32)  # noqa: E731
        return cls(w=full(w), **{k: full(p[k]) for k in ("mu0", "chi", "mu1", "beta")})


def read_map(path: str | Path) -> ReflectanceMap:
    """Read a reflectance map EXR; :class:`InputError` names the file and any missing channel."""
    channels, header = read_exr(path)
    for name in REFLECTANCE_CHANNELS:
        if name not in channels:
            raise InputError(f"missing channel {name!r} (has {sorted(channels)})", path=path, field=name)
    meta = {k[len("jkatana_"):]: v for k, v in header.items()
            if isinstance(k, str) and k.startswith("jkatana_") and k != "jkatana_kind"}
    m = ReflectanceMap.__new__(ReflectanceMap)
    for name in REFLECTANCE_CHANNELS:
        setattr(m, name, np.ascontiguousarray(channels[name], dtype=np.float32))
    m.meta = meta
    return m.validate(path)


# ----------------------------------------------------------------------------- procedural default


def hamon_line(u: np.ndarray, *, base: float = 0.70, notare: float = 0.035,
               gunome: float = 0.03, seed: int = 0) -> np.ndarray:
    """Distance across (v) of the hamon's boundary at ``u``: notare waves plus gunome.

    Notare (のたれ) is a slow undulation (here ~6 periods over the blade with
    random phases); gunome (互の目) a row of rounded bumps toward the mune
    (period ~1.3 % of the length, irregular height). Near the machi the line
    starts straight (yakidashi); in the kissaki it keeps the same fraction of
    the width, so it follows the fukura into a boshi.
    """
    rng = np.random.default_rng(seed)
    u = np.asarray(u, np.float64)
    wave = np.zeros_like(u)
    for k, amp in ((5.5, 1.0), (9.0, 0.45), (14.0, 0.25)):
        wave += amp * np.sin(2 * np.pi * k * u + rng.uniform(0, 2 * np.pi))
    wave /= 1.7
    period = 0.013
    phase = (u / period) % 1.0
    idx = np.floor(u / period).astype(int)
    heights = 0.55 + 0.45 * rng.random(int(1 / period) + 3)
    bump = heights[np.clip(idx, 0, len(heights) - 1)] * np.sin(np.pi * phase) ** 1.5
    ramp = np.clip(u / 0.08, 0, 1)  # yakidashi: straight for the first 8 %
    line = base + ramp * (notare * wave) - ramp * gunome * bump
    return np.clip(line, 0.42, 0.92)


def _hada(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-std wood grain (itame/masame): noise stretched along u."""
    from scipy.ndimage import gaussian_filter

    H, W = shape
    n = rng.standard_normal((H, W))
    grain = gaussian_filter(n, sigma=(0.6 * H / 256, 6.0 * W / 1024), mode="wrap")
    swirl = gaussian_filter(rng.standard_normal((H, W)), sigma=(3 * H / 256, 24 * W / 1024), mode="wrap")
    g = grain + 0.5 * swirl
    return (g - g.mean()) / (g.std() + 1e-12)


#: μ1 of the built-in map's hamon (radians): wider than the paper's 0.05, see :func:`default_map`.
DEFAULT_HAMON_MU: float = 0.2


def default_map(resolution: tuple[int, int] = (256, 1024), *, seed: int = 0,
                transition: float = 0.012, hada_strength: float = 0.12,
                hamon_mu: float = DEFAULT_HAMON_MU) -> ReflectanceMap:
    """The built-in blade's map: hiraji above a notare/gunome hamon, hada grain.

    χ = 79000, β = 43000 and the hiraji's μ0 = 0.05 rad are the paper's fitted
    values (Mochizuki et al., §6.1). The hamon's lobe width is **not**: it is
    `hamon_mu` = 0.2 rad by default, four times the paper's μ1 = 0.05.

    *Why.* The paper fitted μ1 at its goniometer on one measured blade, in the
    incidence plane, and found the hamon's lobe as narrow as the hiraji's; its
    hamon differs mainly in level (β vs χ, camera units), not in shape. In the
    normalised rendering convention (perfect mirror of reflectance F as μ → 0)
    the levels cancel, so with μ0 = μ1 = 0.05 the two regions render almost
    alike (``experiments/render_paper_check.py`` measures this: the hamon is
    invisible). What makes a hamon visible to the eye is the martensite of the
    hardened edge: nie and nioi crystals (tens of µm down to sub-µm) and the
    polisher's hazuya/jizuya finishing scatter light far wider than the
    burnished ji (which is why sword photographers light the blade so the ji
    mirrors a dark field while the hamon glows). 0.15–0.3 rad is a visual
    estimate of that spread, not a measurement; 0.2 rad makes the built-in
    blade's hamon a soft bright band. The built-in map is a demonstration asset:
    for a measured blade, pass fitted parameters (``jkatana fit``) instead.

    **Arguments:**

    - `resolution`: ``(H, W)`` = (pixels across, pixels along).
    - `seed`: the pattern's random seed (deterministic).
    - `transition`: width in v of the soft hiraji → hamon edge (the nioi line).
    - `hada_strength`: relative modulation of μ0 and μ1 by the grain.
    - `hamon_mu`: the hamon's mean μ1 in radians (> 0).

    **Returns:**

    A :class:`ReflectanceMap`: w = 1 above the line (and on the shinogi-ji),
    w = 0 from the line to the edge, a smoothstep between; μ0 = 0.05 rad
    × (1 + hada_strength/2 · grain), μ1 = `hamon_mu` × (1 + hada_strength · grain)
    (a little rougher still at the nie along the line), χ = 79000, β = 43000.
    """
    H, W = int(resolution[0]), int(resolution[1])
    if H < 2 or W < 2:
        raise InputError(f"resolution must be at least (2, 2), got {resolution}", field="resolution")
    if not (np.isfinite(hamon_mu) and hamon_mu > 0):
        raise InputError(f"must be a positive angle in radians, got {hamon_mu!r}", field="hamon_mu")
    rng = np.random.default_rng(seed)
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    line = hamon_line(u, seed=seed)[None, :]
    t = np.clip((v[:, None] - (line - transition)) / (2 * transition), 0, 1)
    w = 1 - t * t * (3 - 2 * t)  # smoothstep: 1 above the line (mune side), 0 toward the edge
    grain = _hada((H, W), rng)
    # nie: sparse bright crystals along the boundary make the hamon a little rougher there
    nie = np.exp(-((v[:, None] - line) / (2.5 * transition)) ** 2) * (rng.random((H, W)) > 0.8)
    p = PAPER_PARAMETERS
    mu0 = p["mu0"] * (1 + 0.5 * hada_strength * grain)
    mu1 = hamon_mu * (1 + hada_strength * grain) * (1 + 0.3 * nie)
    return ReflectanceMap(
        w=w, mu0=np.clip(mu0, 0.2 * p["mu0"], None), chi=np.full((H, W), p["chi"]),
        mu1=np.clip(mu1, 0.2 * hamon_mu, None), beta=np.full((H, W), p["beta"]),
        meta={"source": "procedural default (notare/gunome hamon, hada grain)", "seed": seed,
              "hamon_mu": float(hamon_mu)},
    )

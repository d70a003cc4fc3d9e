"""Photos of a blade under diffuse light, rendered by Mitsuba 3 (Jakob et al., mitsuba-renderer.org).

The oracle for :mod:`jkatana.maps.register`: a blade mesh carrying a known w
map, photographed by an independent renderer the way the paper's fifth stage
photographs a sword (Mochizuki et al.): under diffuse side light, where the
mirror-like hiraji reflects the dark surround and looks dark while the rough
hamon scatters the side light toward the camera and looks bright.

The scene (Mitsuba's Python dict API, nothing of jkatana's renderer):

- the blade: :func:`jkatana.shape.katana.build_blade`'s mesh in metres with
  its vertex normals and (u, v) texture coordinates, written as a binary PLY;
- its BSDF: a ``blendbsdf`` whose weight is the w map (a ``bitmap`` texture,
  raw, bilinear): weight 1 → a smooth ``conductor`` (hiraji, eq. 1's mirror),
  weight 0 → a ``roughconductor`` (GGX, α = :data:`HAMON_ALPHA`), both with
  iron's n, k at 550 nm (Johnson & Christy 1974: n ≈ 2.87, k ≈ 3.0);
- the light: two long ``rectangle`` area lights above and below the blade,
  tilted toward it at ~60° from the flat's normal (far outside the camera's
  mirror cone), each with a radiance ramp along the blade (``unevenness``:
  1 at the machi end, 1 − unevenness at the tip end); a dim ``constant``
  surround (the dark room);
- the background: a plain backdrop behind the blade, a light box (a
  ``rectangle`` with an ``area`` emitter of radiance :data:`BACKDROP_RADIANCE`
  and no reflection) carrying the same ramp as the lights (a diffuse board lit
  by them would look the same, but path-traces far noisier at the few samples
  a test can afford);
- the camera: ``perspective``, aimed at a point of the blade from a direction
  ``tilt_deg`` off the flat's normal (toward the mune, ``azimuth_deg`` around
  it), rolled by ``roll_deg``; on +Z for the omote, on −Z for the ura.

``exposure`` scales the frame (a camera's exposure); Gaussian noise of
``noise`` relative to the median pixel stands in for sensor noise.

Mitsuba's texture lookup of a ``mi.Bitmap`` puts row 0 at v = 0 and reads a
PLY's texture coordinates as written, the reflectance map's own layout
(row 0 = mune): the rendered hamon lies on the ha side (the tests' recovered
maps, compared texel by texel with the truth, would fail otherwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: GGX roughness of the hamon's rough conductor: wide enough to scatter side light into the camera.
HAMON_ALPHA = 0.45
#: Iron at 550 nm (Johnson & Christy 1974), Mitsuba's RGB conductor takes one (n, k) for all channels here.
IRON_ETA, IRON_K = 2.87, 3.0
#: Radiance of the plain backdrop (between the dark hiraji's and the bright hamon's levels).
BACKDROP_RADIANCE = 0.2


def rgb_variant() -> str | None:
    """The fastest RGB variant of Mitsuba 3 that runs here (:func:`validation.mitsuba.mitsuba_variant`)."""
    from validation.mitsuba import mitsuba_variant

    return mitsuba_variant("rgb")


def choji_map(resolution: tuple[int, int] = (256, 1024), *, seed: int = 1) -> np.ndarray:
    """A second hamon pattern: a choji-midare line (clove-bud bumps of uneven height and width,
    v ≈ 0.62–0.85) with a few tobiyaki islands (w = 0 spots) in the hiraji. Returns w (H, W)."""
    rng = np.random.default_rng(seed)
    H, W = resolution
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    line = np.full(W, 0.82)
    pos = 0.04
    while pos < 0.97:
        width = rng.uniform(0.02, 0.05)
        height = rng.uniform(0.08, 0.2)
        line -= height * np.exp(-0.5 * ((u - pos) / (0.35 * width)) ** 2)
        pos += width * rng.uniform(0.8, 1.3)
    line = np.clip(line, 0.55, 0.9)
    t = np.clip((v[:, None] - (line[None, :] - 0.01)) / 0.02, 0, 1)
    w = 1 - t * t * (3 - 2 * t)
    for _ in range(5):  # tobiyaki: isolated hardened spots in the hiraji
        cu, cv = rng.uniform(0.1, 0.85), rng.uniform(0.38, 0.5)
        r = np.hypot((u[None, :] - cu) / 0.012, (v[:, None] - cv) / 0.06)
        w = np.minimum(w, np.clip(r - 0.5, 0, 1) * 2)
    return np.clip(w, 0, 1)


def write_ply(mesh, path: str | Path) -> Path:
    """Binary PLY with positions, vertex normals and (u, v) texture coordinates (Mitsuba reads ``u``, ``v``)."""
    v = np.asarray(mesh.vertices, np.float32)
    n = np.asarray(mesh.vertex_normals, np.float32)
    uv = np.asarray(mesh.visual.uv, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    vert = np.empty(len(v), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                             ("nz", "<f4"), ("u", "<f4"), ("v", "<f4")])
    for i, k in enumerate("xyz"):
        vert[k] = v[:, i]
        vert["n" + k] = n[:, i]
    vert["u"], vert["v"] = uv[:, 0], uv[:, 1]
    face = np.empty(len(f), [("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, f
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
              + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz", "u", "v"))
              + f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    path = Path(path)
    path.write_bytes(header.encode() + vert.tobytes() + face.tobytes())
    return path


@dataclass
class Shot:
    """One photo: where the camera looks from, and how it is exposed.

    ``target_u``: the arc-length fraction of the blade point it aims at (its
    middle across); ``span_m``: the length of blade (m) that ``width`` pixels
    cover at that point; ``side``: "omote" (+Z) or "ura" (−Z).
    """

    target_u: float = 0.5
    span_m: float = 0.84
    width: int = 2400
    height: int = 760
    tilt_deg: float = 10.0
    azimuth_deg: float = 70.0
    roll_deg: float = 4.0
    distance_m: float = 1.2
    side: str = "omote"
    exposure: float = 1.0
    spp: int = 16
    seed: int = 0
    noise: float = 0.01


def camera_frame(spec, shot: Shot):
    """(origin, target, up) of the shot's camera in the blade frame."""
    from jkatana.shape.katana import blade_xy

    xy = blade_xy(spec, np.array([shot.target_u]), np.array([0.5]))[0]
    target = np.array([xy[0], xy[1], 0.0])
    s = 1.0 if shot.side == "omote" else -1.0
    t, a = math.radians(shot.tilt_deg), math.radians(shot.azimuth_deg)
    d = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), s * math.cos(t)])
    origin = target + shot.distance_m * d
    fwd = -d / np.linalg.norm(d)
    up0 = np.array([0.0, 1.0, 0.0])
    up0 = up0 - fwd * (up0 @ fwd)
    up0 /= np.linalg.norm(up0)
    right = np.cross(fwd, up0)
    r = math.radians(shot.roll_deg)
    up = math.cos(r) * up0 + math.sin(r) * right
    return origin, target, up


def render_photo(mesh, w: np.ndarray, shot: Shot, *, workdir: str | Path, unevenness: float = 0.0,
                 variant: str | None = None) -> tuple[np.ndarray, dict]:
    """Render one photo of ``mesh`` carrying the w map ``w`` (H, W; row 0 = mune). Returns
    ``(linear RGB (height, width, 3), camera)`` with the camera as ``{"origin", "target", "up", "fov_x_deg"}``."""
    import mitsuba as mi

    spec = _spec(mesh)
    mi.set_variant(variant or rgb_variant())
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    ply = write_ply(mesh, workdir / "blade_mitsuba.ply")
    origin, target, up = camera_frame(spec, shot)
    fov_x = 2 * math.degrees(math.atan(0.5 * shot.span_m / shot.distance_m))
    s = 1.0 if shot.side == "omote" else -1.0
    L = float(np.ptp(np.asarray(mesh.vertices)[:, 0]))
    ramp = np.linspace(1.0, 1.0 - unevenness, 64, dtype=np.float32)[None, :, None].repeat(2, 0)

    def light(y: float) -> dict:
        # a rectangle of 1.6 × 0.25 m at height y, 0.3 m out on the camera's side, tilted to face the blade
        centre = np.array([L / 2, y, s * 0.3])
        normal = -np.array([0.0, y, s * 0.3]) / math.hypot(y, 0.3)
        tr = (mi.ScalarTransform4f().translate(centre.tolist())
              @ _orient(normal) @ mi.ScalarTransform4f().scale([0.8 * L / 0.7, 0.125, 1.0]))
        return {"type": "rectangle", "to_world": tr,
                "emitter": {"type": "area", "radiance": {"type": "bitmap", "bitmap": mi.Bitmap(8.0 * ramp),
                                                         "raw": True, "wrap_mode": "clamp"}}}

    board = (mi.ScalarTransform4f().translate([L / 2, 0.0, -s * 0.12])
             @ _orient(np.array([0.0, 0.0, s])) @ mi.ScalarTransform4f().scale([1.5, 1.5, 1.0]))
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "room": {"type": "constant", "radiance": {"type": "rgb", "value": 0.01}},
        "light_mune": light(0.55),
        "light_ha": light(-0.55),
        "board": {"type": "rectangle", "to_world": board,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                  "emitter": {"type": "area", "radiance": {"type": "bitmap", "raw": True, "wrap_mode": "clamp",
                                                           "bitmap": mi.Bitmap(BACKDROP_RADIANCE * ramp)}}},
        "blade": {"type": "ply", "filename": str(ply), "face_normals": False,
                  "bsdf": {"type": "blendbsdf",
                           "weight": {"type": "bitmap", "bitmap": mi.Bitmap(np.asarray(w, np.float32)[..., None]),
                                      "raw": True, "filter_type": "bilinear", "wrap_mode": "clamp"},
                           "bsdf_0": {"type": "roughconductor", "distribution": "ggx", "alpha": HAMON_ALPHA,
                                      "eta": IRON_ETA, "k": IRON_K},
                           "bsdf_1": {"type": "conductor", "eta": IRON_ETA, "k": IRON_K}}},
        "camera": {"type": "perspective", "fov": fov_x, "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=target.tolist(),
                                                              up=up.tolist()),
                   "film": {"type": "hdrfilm", "width": shot.width, "height": shot.height,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": shot.spp}},
    })
    img = np.asarray(mi.render(scene, spp=shot.spp, seed=shot.seed), np.float64)[..., :3]
    if shot.noise:
        rng = np.random.default_rng(shot.seed + 1000)
        level = float(np.median(img))
        img = img + rng.normal(0.0, shot.noise * level, img.shape[:2])[..., None]
    img = np.maximum(img * shot.exposure, 0.0)
    return img, {"origin": origin, "target": target, "up": up, "fov_x_deg": fov_x}


def _orient(normal: np.ndarray):
    """A rotation taking +Z (a rectangle's normal in Mitsuba) to ``normal``."""
    import mitsuba as mi

    n = np.asarray(normal, float) / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s = np.linalg.norm(axis)
    if s < 1e-12:
        return mi.ScalarTransform4f() if n[2] > 0 else mi.ScalarTransform4f().rotate([1.0, 0.0, 0.0], 180.0)
    angle = math.degrees(math.atan2(s, float(z @ n)))
    return mi.ScalarTransform4f().rotate((axis / s).tolist(), angle)


def _spec(mesh):
    from jkatana.shape.katana import KatanaSpec

    meta = dict(mesh.metadata.get("katana", {}))
    return KatanaSpec(**meta) if meta else KatanaSpec()


def write_photo(path: str | Path, rgb: np.ndarray) -> Path:
    """Linear RGB EXR (what a RAW converter would give)."""
    from jkatana.io.exr import write_exr

    return write_exr(path, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})


def section_shots(n: int, *, exposures=(1.0, 0.6, 1.5), overlap: float = 0.35, **kw) -> list[Shot]:
    """``n`` overlapping section photos along the blade (each ~1/n of it plus ``overlap`` of a section
    on each side), with the given exposures in turn."""
    shots = []
    for i in range(n):
        c = (i + 0.5) / n
        span = 0.7 * (1.0 / n) * (1 + 2 * overlap)
        shots.append(Shot(target_u=c, span_m=span, width=1600, height=900, exposure=exposures[i % len(exposures)],
                          roll_deg=(-3.0, 5.0, 2.0)[i % 3], tilt_deg=(8.0, 12.0, 6.0)[i % 3],
                          azimuth_deg=(60.0, 100.0, 240.0)[i % 3], distance_m=0.6, seed=i, **kw))
    return shots


def boundary_rows(w: np.ndarray) -> list[np.ndarray]:
    """Per column, the fractional rows (texel-centre units, v = (row + 0.5)/H) where w crosses 0.5."""
    out = []
    for col in w.T:
        a, b = col[:-1], col[1:]
        k = np.flatnonzero((a - 0.5) * (b - 0.5) < 0)
        out.append(k + (a[k] - 0.5) / (a[k] - b[k]))
    return out


def _p95(err: np.ndarray) -> float:
    """95th percentile, inf where it falls on a column with no recovered crossing (no NaN from inf − inf)."""
    if not err.size:
        return float("inf")
    p = float(np.percentile(np.where(np.isfinite(err), err, 1e9), 95, method="higher"))
    return float("inf") if p >= 1e9 else p


def map_errors(w: np.ndarray, truth: np.ndarray, seen: np.ndarray, surface) -> dict:
    """The issue's figures for a recovered w against the truth, over the texels the photos see.

    - ``mean_abs_dw``: mean |Δw| over the seen texels;
    - ``boundary_mm``: per column seen over at least 90 % of its height, the distance along v (mm, the
      blade's local width × Δv) from the true hamon boundary (the last w = 0.5 crossing from the mune
      toward the ha) to the nearest w = 0.5 crossing of the recovered map after a 3×3 median filter
      (inf where it has none); ``boundary_within_1mm``: the fraction of those columns within 1 mm;
      ``boundary_p95_mm``: their 95th percentile.
    """
    from scipy.ndimage import median_filter

    H, W = w.shape
    P = surface.points["omote"]
    width_mm = 1000 * np.linalg.norm(P[0, :, :2] - P[-1, :, :2], axis=1) * H / (H - 1)
    rec = boundary_rows(median_filter(w, size=3))
    tru = boundary_rows(truth)
    cols = np.flatnonzero(seen.mean(0) >= 0.9)
    err = []
    for j in cols:
        if len(tru[j]) == 0:
            continue
        t = tru[j][-1]
        err.append(np.min(np.abs(rec[j] - t)) / H * width_mm[j] if len(rec[j]) else np.inf)
    err = np.asarray(err)
    return {"mean_abs_dw": float(np.mean(np.abs(w - truth)[seen])),
            "boundary_within_1mm": float(np.mean(err <= 1.0)) if err.size else 0.0,
            "boundary_p95_mm": _p95(err),
            "columns": int(err.size), "seen_percent": float(100 * seen.mean())}


#: The test cases: name → (blade measures (nagasa, sori) in metres, w pattern, shots).
CASES = ("whole", "sections", "sides")


def render_case(case: str, workdir: str | Path, *, spp: int = 4, resolution: tuple[int, int] = (256, 1024),
                unevenness: float = 0.0, tilt_deg: float | None = None, shots: list | None = None):
    """Render one of :data:`CASES` into ``workdir``: ``(mesh, true w, photo paths)``.

    - ``whole``: the built-in blade with the built-in hamon, one 2400×760 photo (2000 px along the blade),
      10° off the normal, rolled 4°;
    - ``sections``: a shorter, more curved blade (nagasa 0.60 m, sori 25 mm) with :func:`choji_map`, three
      overlapping 1600×900 section photos exposed ×1, ×0.6, ×1.5, 6–12° off the normal, rolled −3°, 5°, 2°;
    - ``sides``: the built-in blade and hamon, one omote photo and one ura photo (12° off, rolled −5°).

    ``tilt_deg`` overrides every shot's angle from the normal; ``shots`` replaces the case's shots.
    """
    import dataclasses

    from jkatana.maps import default_map
    from jkatana.shape.katana import KatanaSpec, build_blade

    workdir = Path(workdir)
    if case == "sections":
        mesh = build_blade(KatanaSpec(nagasa=0.60, sori=0.025))
        truth = choji_map(resolution)
        case_shots = section_shots(3, spp=spp)
    elif case in ("whole", "sides"):
        mesh = build_blade(KatanaSpec())
        truth = default_map(resolution).w
        case_shots = [Shot(spp=spp)]
        if case == "sides":
            case_shots.append(Shot(spp=spp, side="ura", roll_deg=-5.0, tilt_deg=12.0, azimuth_deg=110.0, seed=7))
    else:
        raise ValueError(f"unknown case {case!r} (one of {CASES})")
    if shots is not None:
        case_shots = shots
    if tilt_deg is not None:
        case_shots = [dataclasses.replace(s, tilt_deg=tilt_deg) for s in case_shots]
    paths = []
    for i, shot in enumerate(case_shots):
        img, _ = render_photo(mesh, truth, shot, workdir=workdir, unevenness=unevenness)
        paths.append(write_photo(workdir / f"{case}_{i}_{shot.side}.exr", img))
    return mesh, truth, paths


def crop_comparison(photo: str | Path, truth: np.ndarray, surface) -> dict:
    """The same photo through the straight-rectangle path (``jkatana map PHOTO --crop``): the crop is the
    bounding box of the blade found in the photo (what a user would draw around it), the figures those of
    :func:`map_errors` over the whole map."""
    from jkatana.maps.photo import map_from_photo, read_photo
    from jkatana.maps.outline import find_blade

    y = read_photo(photo)
    ys, xs = np.nonzero(find_blade(y).mask)
    crop = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    m = map_from_photo(y, resolution=truth.shape, crop=crop)
    return {**map_errors(m.w, truth, np.ones(truth.shape, bool), surface), "crop": crop}

"""From a validated :class:`~jkatana.render.scene.Scene` to frames and files.

:func:`prepare` loads everything once (mesh, map, region parameter files,
optical constants, environment and its sampling tables) and decides the
static shading :class:`~jkatana.render.shading.Plan` (effects on demand);
:func:`render_view` renders one camera / environment rotation;
:func:`write_outputs` writes the EXR (linear XYZ) and PNG with metadata.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import platform
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jkatana.errors import InputError
from jkatana.render.camera import Camera
from jkatana.render.film import display, scene_exposure, film_weights, write_png, write_spectral_exr, write_xyz_exr
from jkatana.render.frame import Frame, pixel_blocks, render_frame
from jkatana.render.scene import LIMITS, RENDER_MODES, Scene
from jkatana.render.scenefile import scene_to_toml
from jkatana.models.lobe_id import LobeId
from jkatana.render.regions import region_lobe_keys
from jkatana.render.environment import Environment, build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.integrators import integrator_for
from jkatana.render.plan import LOBE_MODES, MIRROR_MU, Light, Plan
from jkatana.spectral.grid import WavelengthGrid


@dataclasses.dataclass
class Prepared:
    """Everything a frame needs, loaded and on device."""

    scene: Scene
    grid: WavelengthGrid
    dtype: object
    geometry: object
    maps: np.ndarray           # (H, W, 3): w, mu0, mu1
    material: Material
    env: Environment
    env_info: dict
    lights: Light | None
    plan: Plan
    cmf: np.ndarray
    load_s: float
    occluders: object = None   # gbuffer.Occluders, or None: no visibility rays


def load_geometry(scene: Scene):
    """The scene's geometry: ``("sphere", center, radius)`` or a trimesh mesh with per-vertex UVs
    (constant UVs for a mesh without them under a uniform material; refused under a map)."""
    g = scene.geometry
    if g.kind == "sphere":
        return ("sphere", g.center, g.radius)
    if g.mesh == "builtin:katana":
        from jkatana.shape.katana import default_blade

        return default_blade()
    import trimesh

    try:
        mesh = trimesh.load(g.mesh, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise InputError(f"not a readable mesh ({err})", path=g.mesh, field="geometry.mesh") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError("no triangles", path=g.mesh, field="geometry.mesh")
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        if scene.material.map is not None:
            raise InputError("mesh has no per-vertex UVs, which the reflectance map needs: make them with "
                             "`jkatana shape MESH --uv blade` (or `--uv xatlas`), or give a uniform material "
                             "(w, mu0, mu1) instead of a map", path=g.mesh, field="geometry.mesh")
        # a uniform material reads the same value everywhere: any UVs do
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(mesh.vertices), 2)))
    return mesh


#: The paper's lobe of each region: a parameter file of that model is rendered by the paper's path.
PAPER_LOBE = {"hiraji": "gaussian", "hamon": "gaussian-vcavity"}


def load_maps(scene: Scene, geometry) -> tuple[np.ndarray, float, float]:
    """``(maps (H, W, 3) of w, μ0, μ1; χ; β)`` with region parameter files applied (:func:`load_material`)."""
    maps, chi, beta, _ = load_material(scene, geometry)
    return maps, chi, beta


def load_material(scene: Scene, geometry) -> tuple[np.ndarray, float, float, dict]:
    """``(maps (H, W, 3) of w, μ0, μ1; χ; β; lobes)`` with region parameter files applied.

    A region's parameter file may hold any lobe ``jkatana fit`` writes. The map's
    spatial modulation of the region's width (hada) is kept, rescaled so that its
    median is the fitted width (μ of the paper's lobes, the primary α of the
    others; a two-lobe's haze width keeps its ratio to it). ``lobes`` maps each
    region to ``None`` (the paper's lobe) or the lobe's
    :class:`~jkatana.models.lobe_id.LobeId` at unit width (``Plan.hiraji_lobe`` /
    ``hamon_lobe``). The file's scale (χ, β or s) is the calibrated scale of its
    region (``[material] calibration``; unused in the normalised convention).
    """
    mat = scene.material
    if mat.map is None:
        u = mat.uniform
        maps = np.array([[[u.w, u.mu0, u.mu1]]], np.float32).repeat(2, 0).repeat(2, 1)
        chi, beta = 79000.0, 43000.0
    else:
        from jkatana.maps.reflectance_map import default_map, read_map

        rmap = default_map() if mat.map == "builtin" else read_map(mat.map)
        _check_map_size(rmap.shape, geometry, mat.map)
        maps = np.stack([rmap.w, rmap.mu0, rmap.mu1], -1).astype(np.float32)
        chi, beta = float(np.median(rmap.chi)), float(np.median(rmap.beta))
    lobes = {"hiraji": None, "hamon": None}
    for region, ch in (("hiraji", 1), ("hamon", 2)):
        region_file = getattr(mat, region)
        if region_file is None:
            continue
        from jkatana.fit.params import read_params

        p = read_params(region_file)
        if p.model in PAPER_LOBE and p.model != region:
            raise InputError(f"is a {p.model!r} parameter file, expected {region!r} or another lobe "
                             f"(beckmann, ggx, gtr, two-lobe)", path=region_file, field=f"material.{region}")
        width = p.mu
        if p.model != region:
            width, lobes[region] = _file_lobe(p, region_file, region)
        # keep the map's spatial modulation (hada), rescaled to the fitted width
        base = maps[..., ch]
        maps[..., ch] = base * (width / max(float(np.median(base)), 1e-12))
        if region == "hiraji":
            chi = p.scale
        else:
            beta = p.scale
    return maps, chi, beta, lobes


def _file_lobe(p, path, region) -> tuple[float, LobeId]:
    """``(width, identity)`` of a parameter file's lobe (its ``lobe`` entry, else rebuilt from its values)."""
    from jkatana.models.lobes import lobe_from_params

    field = f"material.{region}"
    try:
        if p.lobe is not None:
            params = p.lobe
        else:  # a file written without the lobe entry: the model's lobe at its values
            from jkatana.models.fitted import FIT_MODELS

            fm = FIT_MODELS[p.model]
            params = fm.build(jnp.asarray(fm.shape_from_natural(p.values))).to_params()
        lobe_from_params(params)  # every field known and well-formed
        return LobeId.shape_of(params)
    except (ValueError, TypeError, KeyError) as err:
        raise InputError(f"lobe entry is not a lobe jkatana renders ({err})", path=path,
                         field=f"{field} (lobe)") from None


def check_lobe_mode(lobes: dict, scene: Scene, mode: str) -> None:
    """One :class:`InputError` line when a region's lobe (not the paper's) cannot be rendered in ``mode``.

    :data:`~jkatana.render.plan.LOBE_MODES` render any lobe. The paper's modes keep the paper's estimator
    (Gaussian-weighted rays within 2.5 μ of the mirror direction), which would cut off a microfacet lobe's
    tails.
    """
    if mode in LOBE_MODES:
        return
    why = "is the paper's estimator: Gaussian-weighted rays within 2.5 μ of the mirror direction, which would " \
          "cut off this lobe's tails"
    for region, key in lobes.items():
        if key is not None:
            raise InputError(f"holds a {key.family!r} lobe, which renders in modes {', '.join(LOBE_MODES)} only "
                             f"(mode {mode!r} {why}): set [render] mode or --mode",
                             path=getattr(scene.material, region), field=f"material.{region}")


def _check_map_size(shape, geometry, where):
    """A map's (rows across, columns along) must not be transposed w.r.t. the mesh's UV domain."""
    if isinstance(geometry, tuple):
        return
    H, W = shape
    mesh = geometry
    uv = np.asarray(mesh.visual.uv)
    tri = mesh.faces
    # physical length per unit u and per unit v, from the triangles' UV Jacobians
    p = mesh.vertices[tri]
    t = uv[tri]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-12
    if not ok.any():
        return
    Pu = (e1[ok] * d2[ok, 1:2] - e2[ok] * d1[ok, 1:2]) / det[ok, None]
    Pv = (e2[ok] * d1[ok, 0:1] - e1[ok] * d2[ok, 0:1]) / det[ok, None]
    along, across = np.median(np.linalg.norm(Pu, axis=-1)), np.median(np.linalg.norm(Pv, axis=-1))
    if along <= 0 or across <= 0:
        return
    mesh_aspect = along / across        # metres along u per metre across v
    map_aspect = W / H                  # map columns per row
    if (mesh_aspect > 2 and map_aspect < 1) or (mesh_aspect < 0.5 and map_aspect > 1):
        raise InputError(f"map is {H}×{W} (rows across v × columns along u) but the mesh's UV domain is "
                         f"{mesh_aspect:.1f}× longer along u than across v: size does not match the mesh "
                         f"(transposed map?)", path=None if where == "builtin" else where, field="material.map")


def load_environment(scene: Scene, grid: WavelengthGrid) -> np.ndarray:
    """The scene's environment as ``(H, W, wl)`` float32 spectral radiance on ``grid``
    (through the environment cache, :mod:`jkatana.light.cache`)."""
    from jkatana.light.cache import cached_radiance, radiance_key

    return cached_radiance(radiance_key(scene.environment, grid), lambda: _build_radiance(scene, grid))


def _build_radiance(scene: Scene, grid: WavelengthGrid) -> np.ndarray:
    e = scene.environment
    if e.type == "sky":
        from jkatana.light.sky import hosek_wilkie_sky

        env = hosek_wilkie_sky(e.elevation_deg, e.azimuth_deg, e.turbidity, e.albedo, e.resolution, grid,
                               sun=e.sun)
        return np.asarray(env.radiance, np.float32)
    if e.type in ("exr", "hdr"):
        from jkatana.light.envmap import load_envmap

        env = load_envmap(e.path, grid, upsampling=e.upsampling, scale=e.scale, colourspace=e.colourspace)
        return np.asarray(env.radiance, np.float32)
    H, W = e.resolution
    return np.full((H, W, grid.size), e.radiance, np.float32)


def rotation_y(deg: float) -> np.ndarray:
    """Right-handed rotation about +Y used as world → map: rotating the environment by ``deg``
    moves a feature at compass azimuth a to a + deg (azimuth clockwise from −Z towards +X)."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def prepare(scene: Scene, *, mode: str | None = None, samples: int | None = None,
            rank: int | None = None, env_radiance: np.ndarray | None = None,
            split_sun: bool | None = None, max_memory: int | None = None) -> Prepared:
    """Load the scene's assets and decide the shading plan (effects on demand).

    ``mode``, ``samples`` and ``rank`` override the scene's (``None``: the scene's); an override is
    checked as the scene's own field is (``samples = 0`` is an error, not "the scene's count").
    ``split_sun``: split the environment's compact bright sources off as cap lights
    (:func:`~jkatana.render.environment.build_environment`); ``None``: the scene's ``render.split_sun``,
    and where that is unset the mode's default (:attr:`Integrator.splits_sun
    <jkatana.render.integrators.Integrator.splits_sun>`; never in
    ``paper-published``). The scene's ``render.env_window`` goes to :attr:`Plan.env_window
    <jkatana.render.plan.Plan.env_window>`. ``max_memory``: the budget (bytes) a map file's whole spectra
    must fit, else it is streamed (:func:`jkatana.render.streamed.streams`).
    """
    mode, samples = _mode_and_samples(scene, mode, samples)
    t0 = time.perf_counter()
    grid = scene.spectral.grid
    dtype = jnp.float64 if scene.render.precision == "float64" else jnp.float32
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    geometry = load_geometry(scene)
    maps, chi, beta, lobes = load_material(scene, geometry)
    check_lobe_mode(lobes, scene, mode)
    mat = _material(scene, grid, dtype, chi, beta)
    env, factored, resid, env_rank = _environment(scene, grid, dtype, integrator_for(mode), maps, lobes, rank=rank,
                                                  env_radiance=env_radiance, split_sun=split_sun,
                                                  max_memory=max_memory)
    lights = _lights(scene, grid, dtype)
    plan = _plan(scene, mode, samples, maps, lobes, factored)
    occluders = None
    if scene.occluders:
        from jkatana.render.gbuffer import Occluders, occluder_mesh

        occluders = Occluders(occluder_mesh(scene.occluders))
    env_info = {"channels": int(env.channels.shape[-1]), "factored": factored, "rank_residual": resid,
                "grey": bool(factored and env_rank is None), "resolution": list(env.channels.shape[:2]),
                "caps": 0 if env.caps is None else env.caps.count}
    return Prepared(scene, grid, dtype, geometry, maps, mat, env, env_info, lights, plan,
                    film_weights(grid), time.perf_counter() - t0, occluders)


def _mode_and_samples(scene: Scene, mode: str | None, samples: int | None) -> tuple[str, int]:
    """:func:`prepare`'s mode and sample count: the overrides, or the scene's, checked as the scene's fields are."""
    mode = scene.render.mode if mode is None else mode
    samples = scene.render.samples if samples is None else samples
    if mode not in RENDER_MODES:
        raise InputError(f"must be one of {list(RENDER_MODES)}, got {mode!r}", field="mode")
    if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= LIMITS["samples"]:
        raise InputError(f"must be an integer in [1, {LIMITS['samples']}], got {samples!r}", field="samples")
    return mode, samples


def _material(scene: Scene, grid: WavelengthGrid, dtype, chi, beta) -> Material:
    """The shader's :class:`Material`: the Fresnel table of the scene's optical constants on ``grid`` (through
    the cache, :mod:`jkatana.light.cache`) and the regions' scales."""
    from jkatana.light.cache import cached_tree, fresnel_key
    from jkatana.spectral.optical_constants import load as load_oc

    try:
        n, k = load_oc(scene.material.optical_constants).on_grid(grid)
    except InputError as err:
        raise InputError(str(err), field="material.optical_constants") from None
    table = cached_tree(fresnel_key(n, k, dtype), lambda: fresnel_table(jnp.asarray(n, dtype), jnp.asarray(k, dtype)),
                        kind="fresnel")
    return Material(jnp.asarray(table, dtype), jnp.asarray(chi, dtype), jnp.asarray(beta, dtype))


def _environment(scene: Scene, grid: WavelengthGrid, dtype, integrator, maps, lobes: dict, *, rank, env_radiance,
                 split_sun, max_memory) -> tuple[Environment, bool, float, int | None]:
    """``(environment, factored, rank residual, rank or None)``: the scene's environment as ``integrator`` shades
    it (projected on ``rank`` principal spectra for a low-rank one; prefiltered levels for the maps' widths and the
    regions' lobes; the sun split off or not; sampling tables only for a mode that samples the map), built once
    per content (:mod:`jkatana.light.cache`), streamed when a map file's whole spectra do not fit ``max_memory``
    (:func:`jkatana.render.streamed.streams`), and rotated."""
    from jkatana.light.cache import cached_tree, environment_key, radiance_key

    env_rank = (scene.render.rank if rank is None else rank) if integrator.low_rank else None
    mus = ()
    if integrator.prefiltered:
        lo = max(float(np.min(maps[..., 1:])), 1e-3)
        hi = max(float(np.max(maps[..., 1:])), lo * 1.01)
        mus = tuple(np.geomspace(lo, hi, 4))
    pre_lobes = region_lobe_keys(lobes, scene.material.calibration) if mus else (None, None)
    split_sun = scene.render.split_sun if split_sun is None else split_sun
    split = integrator.splits_sun if split_sun is None else bool(split_sun)
    if integrator.whole_map and split:
        raise InputError(f"the {integrator.name} mode shades the whole map: no sun split (render.split_sun)",
                         field="mode")
    kw = dict(rank=env_rank, prefilter_mus=mus, prefilter_resolution=128, dtype=dtype, split_sun=split,
              sampling=integrator.sampled)
    rad_key = radiance_key(scene.environment, grid) if env_radiance is None else None
    env_key = None if rad_key is None else environment_key(rad_key, **kw)
    if env_key is not None and pre_lobes != (None, None):
        env_key += "-" + hashlib.sha256(repr(pre_lobes).encode()).hexdigest()[:16]

    from jkatana.render.streamed import build_scene_streamed, streamed_key, streams

    streamed = env_radiance is None and streams(scene, max_memory)
    env_key = streamed_key(env_key) if streamed else env_key

    def build():
        if streamed:
            return build_scene_streamed(scene, grid, prefilter_lobes=pre_lobes, **kw)
        radiance = load_environment(scene, grid) if env_radiance is None else env_radiance
        return build_environment(radiance, grid=grid, prefilter_lobes=pre_lobes, **kw)

    env, factored, resid = cached_tree(env_key, build)
    env = eqx.tree_at(lambda e: e.rotation, env, jnp.asarray(rotation_y(scene.environment.rotation_deg), dtype))
    return env, factored, resid, env_rank


def _lights(scene: Scene, grid: WavelengthGrid, dtype) -> Light | None:
    """The scene's point and directional lights as the shader's :class:`Light`, or ``None`` without any."""
    if not scene.lights:
        return None
    from jkatana.spectral.colorimetry import illuminant

    vec = np.array([lt.vector for lt in scene.lights], np.float64)
    kind = np.array([0.0 if lt.type == "point" else 1.0 for lt in scene.lights])
    spec = np.stack([illuminant(lt.spectrum, grid) / 100.0 * lt.intensity for lt in scene.lights])
    return Light(jnp.asarray(vec, dtype), jnp.asarray(kind, dtype), jnp.asarray(spec, dtype))


def _plan(scene: Scene, mode: str, samples: int, maps, lobes: dict, factored: bool) -> Plan:
    """The static shading plan, effects on demand decided here, on the host, from the data: hiraji only where
    some w > 0, hamon where some w < 1, a perfect-mirror hiraji where every hiraji μ0 < ``MIRROR_MU``."""
    w = maps[..., 0]
    hiraji = bool((w > 0).any())
    hamon = bool((w < 1).any())
    mirror = (hiraji and lobes["hiraji"] is None
              and float(np.max(np.where(w > 0, maps[..., 1], 0.0))) < MIRROR_MU)
    return Plan(mode=mode, samples=int(samples), hiraji=hiraji, hamon=hamon, mirror=mirror,
                env_sampling=True, factored=factored, lights=len(scene.lights),
                calibration=scene.material.calibration, hiraji_lobe=lobes["hiraji"], hamon_lobe=lobes["hamon"],
                spectral=scene.output.spectral and not factored,
                visibility=bool(scene.occluders), env_window=scene.render.env_window)


def camera_for(scene: Scene, view: int = 0, views: int = 1) -> Camera:
    """The scene's camera; with ``views > 1`` the ``view``-th of ``views`` azimuths evenly around the target."""
    c = scene.camera
    w, h = c.resolution
    roll = math.radians(c.roll_deg)
    if c.type == "orbit":
        az = c.azimuth_deg + 360.0 * view / views
        cam = Camera.orbit(c.target, c.distance, az, c.elevation_deg, fov_deg=c.fov_deg,
                           width=w, height=h, up=(0.0, 1.0, 0.0))
    else:
        pos = np.subtract(c.position, c.look_at) @ rotation_y(-360.0 * view / views).T + c.look_at
        cam = Camera(tuple(pos), c.look_at, c.up, c.fov_deg, w, h)
    if roll:
        right, up, _ = cam.frame()
        new_up = math.cos(roll) * up + math.sin(roll) * right
        cam = dataclasses.replace(cam, up=tuple(new_up))
    return cam


def render_view(prep: Prepared, view: int = 0, views: int = 1, light: int = 0, lights: int = 1,
                *, seed: int | None = None, supersample: int | None = None) -> Frame:
    """Render one view (camera azimuth step) under one lighting (environment rotation step).

    ``supersample = s > 1`` (default 1) renders
    ``s × s`` subpixels per pixel, each pixel's subpixels sharing one stratified sample set
    (:func:`~jkatana.render.frame.render_frame`), and box-averages them: the returned frame has the
    camera's resolution; its mask is the pixels whose subpixels all hit the object.
    """
    scene = prep.scene
    env = prep.env
    if lights > 1 or light:
        rot = rotation_y(scene.environment.rotation_deg + 360.0 * light / lights)
        env = eqx.tree_at(lambda e: e.rotation, env, jnp.asarray(rot, prep.dtype))
    cam = camera_for(scene, view, views)
    from jkatana.render.check import warn_scene

    warn_scene(prep.geometry, cam)  # camera inside the object, wrong scale, empty frame: one line
    s = scene.render.seed if seed is None else seed
    ss = int(supersample or 1)
    if ss > 1:
        cam = dataclasses.replace(cam, width=cam.width * ss, height=cam.height * ss)
    f = render_frame(prep.plan, prep.material, env, prep.lights, prep.geometry, cam, prep.maps, prep.cmf,
                     seed=s + 7919 * view + 104729 * light, dtype=prep.dtype, chunk=scene.render.chunk,
                     occluders=prep.occluders, supersample=ss)
    if ss == 1:
        return f

    def box(a):
        return pixel_blocks(a, ss).mean((1, 3)).astype(a.dtype)

    return dataclasses.replace(f, xyz=box(f.xyz), mask=pixel_blocks(f.mask, ss).all((1, 3)),
                               spectra=None if f.spectra is None else box(f.spectra),
                               stats={**f.stats, "supersample": ss})


def exposure_for(prep: Prepared, frame: Frame) -> float:
    """The film's exposure, or with ``"auto"`` the rule :func:`~jkatana.render.film.scene_exposure`
    shares with the interactive viewer."""
    e = prep.scene.film.exposure
    if e != "auto":
        return float(e)
    return scene_exposure(frame.xyz, frame.mask)


def metadata(prep: Prepared, frame: Frame, exposure: float, extra: dict | None = None) -> dict:
    """What every output file carries: version, the validated scene (TOML), grid, plan, timing, devices."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("jkatana")
    except PackageNotFoundError:  # pragma: no cover
        ver = "unknown"
    p = prep.plan
    return {
        "jkatana_version": ver,
        "jkatana_scene": scene_to_toml(prep.scene),
        "jkatana_grid": f"{prep.grid.start:g}-{prep.grid.stop:g} nm step {prep.grid.step:g} ({prep.grid.size})",
        "jkatana_mode": p.mode,
        "jkatana_samples": int(p.samples),
        "jkatana_plan": json.dumps(dataclasses.asdict(p)),
        "jkatana_environment": json.dumps(prep.env_info),
        "jkatana_timing": json.dumps({k: round(v, 4) for k, v in frame.timing.items()}),
        "jkatana_exposure": float(exposure),
        "jkatana_devices": f"{len(jax.local_devices())} x {jax.default_backend()}",
        "jkatana_xyz_normalisation": "k = 1/sum(ybar dlambda): flat radiance 1 -> Y = 1",
        "jkatana_machine": platform.node(),
        **(extra or {}),
    }


def write_outputs(prep: Prepared, frame: Frame, stem: Path, extra: dict | None = None) -> dict:
    """Write ``stem.exr`` (linear XYZ + mask), ``stem.png`` and, on request, ``stem_spectral.exr``."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    ex = exposure_for(prep, frame)
    meta = metadata(prep, frame, ex, extra)
    film = prep.scene.film
    rgb = display(frame.xyz, film.colourspace, film.transfer, exposure=ex)
    paths = {}
    if frame.spectra is not None:
        paths["spectral"] = write_spectral_exr(stem.with_name(stem.name + "_spectral.exr"), frame.spectra,
                                               prep.grid, meta)
    paths["exr"] = write_xyz_exr(stem.with_suffix(".exr"), frame.xyz, frame.mask, meta)
    # the PNG last: its presence marks a finished frame (batch resume)
    paths["png"] = write_png(stem.with_suffix(".png"), rgb, meta)
    return paths


@functools.lru_cache(maxsize=4)
def _cached_prepare(scene_path: str, mode, samples):  # pragma: no cover - used by dask workers
    from jkatana.render.scenefile import load_scene

    return prepare(load_scene(scene_path), mode=mode, samples=samples)

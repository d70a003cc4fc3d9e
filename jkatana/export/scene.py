"""A scene as an exporter sees it: what ``jkatana render`` would shade, resolved once for every target.

:func:`resolve` loads the scene with the renderer's own loaders
(:func:`~jkatana.render.renderer.load_geometry`,
:func:`~jkatana.render.renderer.load_material`, the camera of
:func:`~jkatana.render.renderer.camera_for`), so an export holds the same
mesh, map, lobes and optical constants as a frame. Each region's lobe is built
the way :mod:`jkatana.render.regions` builds it — the paper's
:class:`~jkatana.models.lobes.Gaussian` / :class:`~jkatana.models.lobes.GaussianVCavity`,
or the parameter file's lobe in its energy-normalised form — at one width:
other renderers take one lobe per material, where jkatana's map varies the
width per texel (the hada grain). The width exported is the median of the map's
width over the texels where the region dominates (w > ½ for the hiraji, w < ½
for the hamon); :attr:`RegionLobe.spread` keeps the 5th–95th percentiles so
that a user sees what the single width leaves out.

The environment goes out as linear Rec. 709 RGB (:func:`environment_rgb`),
the way Mitsuba 3 and pbrt-v4 take environment maps: jkatana's spectral
radiance integrated against the CIE 1931 observer (eq. 6 of Mochizuki et al.)
and divided by 106.75 nm (≈ ∫ȳ dλ, Mitsuba's film normalisation), so that the
other renderer's RGB → spectrum upsampling (Jakob & Hanika 2019 × D65 in
Mitsuba's spectral variants) gives a spectrum of the same colour and
luminance back.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jkatana.errors import InputError

#: Wavelengths (nm) at which spectra go out: the CIE 1931 observer's domain, which Mitsuba's spectral
#: variants sample (a spectrum given on a narrower range reads as 0 outside it there).
EXPORT_WAVELENGTHS = np.arange(360.0, 831.0, 5.0)
#: Mitsuba 3's film normalisation: its spectral film divides ∫ S x̄ȳz̄ dλ by this (≈ ∫ȳ dλ, nm).
MITSUBA_Y_NORM = 106.75
#: The paper's lobe of each region (Mochizuki et al., eqs. 1 and 2).
PAPER_LOBES = {"hiraji": "gaussian", "hamon": "gaussian-vcavity"}


@dataclasses.dataclass(frozen=True)
class RegionLobe:
    """One region's lobe as exported: the renderer's lobe object at one width.

    **Fields:** `region` (``"hiraji"``/``"hamon"``); `lobe` (a :class:`jkatana.models.lobes.Lobe`, float64,
    unbatched); `width` (its primary width: μ of the paper's lobes, α of the others); `spread` (5th and 95th
    percentile of the map's width where the region dominates); `gain` (the factor the renderer applies to
    the lobe's value: s/K in the calibrated convention, else 1); `mirror` (a hiraji narrower than the
    renderer's mirror limit: a smooth conductor).
    """

    region: str
    lobe: object
    width: float
    spread: tuple[float, float]
    gain: float = 1.0
    mirror: bool = False

    @property
    def family(self) -> str:
        return "mirror" if self.mirror else self.lobe.name


@dataclasses.dataclass
class Resolved:
    """A loaded scene for export: geometry, the per-texel blend weight, each region's lobe, the camera,
    the conductor's n and k on :data:`EXPORT_WAVELENGTHS`."""

    scene: object
    geometry: object            # trimesh.Trimesh with per-vertex UVs, or ("sphere", center, radius)
    w: np.ndarray               # (H, W) float32 blend weight of the hiraji (eq. 5); row 0 = v = 0
    regions: dict               # {"hiraji": RegionLobe | None, "hamon": RegionLobe | None}
    camera: object              # jkatana.render.camera.Camera
    n: np.ndarray
    k: np.ndarray

    @property
    def reach(self) -> float:
        """The size of the scene (m): the object's bounding radius plus the camera's distance from its centre;
        emitters placed far beyond it (a cap at 1000× this) are at infinity for every point of the scene."""
        geom = self.geometry
        if isinstance(geom, tuple):
            c, r = np.asarray(geom[1], np.float64), float(geom[2])
        else:
            lo, hi = np.asarray(geom.bounds, np.float64)
            c, r = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
        return r + float(np.linalg.norm(np.subtract(self.camera.position, c)))

    @property
    def uniform_w(self) -> float | None:
        """The blend weight where it is the same on every texel, else ``None``."""
        lo, hi = float(self.w.min()), float(self.w.max())
        return lo if hi - lo < 1e-6 else None


def _spread(width: np.ndarray, where: np.ndarray) -> tuple[float, tuple[float, float]]:
    vals = width[where] if where.any() else width.ravel()
    return float(np.median(vals)), (float(np.percentile(vals, 5)), float(np.percentile(vals, 95)))


def region_lobe(region: str, key, width: float, spread, *, calibration: float | None, scale: float) -> RegionLobe:
    """The lobe ``jkatana render`` shades a region with (:mod:`jkatana.render.regions`), at ``width``.

    ``key`` is the region's lobe key from :func:`~jkatana.render.renderer.load_material` (``None``: the
    paper's lobe); ``scale`` the region's χ, β or s (used in the calibrated convention only).
    """
    import jax
    import jax.numpy as jnp

    from jkatana.models.lobes import Gaussian, GaussianVCavity
    from jkatana.render.plan import MIRROR_MU

    with jax.enable_x64(True):
        mu = jnp.asarray(width, jnp.float64)
        if key is None:
            cls = Gaussian if region == "hiraji" else GaussianVCavity
            if calibration is None:
                lobe, gain = cls(mu, normalised=True), 1.0
            else:
                lobe, gain = cls(mu, jnp.asarray(scale / calibration, jnp.float64), normalised=False), 1.0
        else:
            lobe = key.rendered(calibration).at_width(mu, jnp.float64)
            gain = 1.0 if calibration is None else scale / calibration
    mirror = key is None and region == "hiraji" and width < MIRROR_MU
    return RegionLobe(region, lobe, float(width), spread, float(gain), mirror)


def resolve(scene) -> Resolved:
    """Load ``scene`` (a :class:`jkatana.render.scene.Scene`) for export (module docstring)."""
    from jkatana.render.renderer import camera_for, load_geometry, load_material
    from jkatana.spectral.grid import WavelengthGrid
    from jkatana.spectral.optical_constants import load as load_oc

    geometry = load_geometry(scene)
    maps, chi, beta, lobes = load_material(scene, geometry)
    w = np.asarray(maps[..., 0], np.float32)
    cal = scene.material.calibration
    regions = {"hiraji": None, "hamon": None}
    if (w > 0).any():
        width, spread = _spread(maps[..., 1], w > 0.5)
        regions["hiraji"] = region_lobe("hiraji", lobes["hiraji"], width, spread, calibration=cal, scale=chi)
    if (w < 1).any():
        width, spread = _spread(maps[..., 2], w < 0.5)
        regions["hamon"] = region_lobe("hamon", lobes["hamon"], width, spread, calibration=cal, scale=beta)
    grid = WavelengthGrid(float(EXPORT_WAVELENGTHS[0]), float(EXPORT_WAVELENGTHS[-1]), 5.0)
    try:
        n, k = load_oc(scene.material.optical_constants).on_grid(grid)
    except InputError as err:
        raise InputError(str(err), field="material.optical_constants") from None
    return Resolved(scene, geometry, w, regions, camera_for(scene), np.asarray(n, np.float64),
                    np.asarray(k, np.float64))


@dataclasses.dataclass(frozen=True)
class CapLight:
    """A compact bright source split off the environment: a spherical cap of uniform spectral radiance.

    **Fields:** `direction` (unit world vector towards its centre, the scene's rotation applied); `radius`
    (angular radius, rad); `radiance` (spectral radiance on `wavelengths`, the map's units); `wavelengths`.
    """

    direction: tuple
    radius: float
    radiance: np.ndarray
    wavelengths: np.ndarray


def _to_rgb(radiance: np.ndarray, grid) -> np.ndarray:
    from jkatana.spectral.colorimetry import xyz_to_linear_rgb, xyz_weights

    xyz = np.tensordot(np.asarray(radiance, np.float64), xyz_weights(grid), axes=([-1], [0])) / MITSUBA_Y_NORM
    return np.maximum(xyz_to_linear_rgb(xyz, "ITU-R BT.709"), 0.0).astype(np.float32)


def environment_rgb(scene, *, split: bool = True) -> tuple[np.ndarray | None, list[CapLight]]:
    """The scene's environment as ``(H, W, 3)`` float32 linear Rec. 709 RGB (module docstring), row 0 at the
    zenith as in jkatana's latitude–longitude layout (``None`` for a constant environment), and the
    compact bright sources split off it (:func:`jkatana.light.sun.split_compact_sources`, the renderer's
    criterion) as :class:`CapLight` s, when ``split``.

    Split, a sun keeps its spectrum and its exact power as a cap; left in an RGB map, another renderer
    interpolates the sun's texels with the sky's around them (Mitsuba's spectral ``envmap`` interpolates
    the texels' RGB → spectrum coefficients and their scales separately, which tints a one-texel sun's
    surroundings with the sky's colour at the sun's power).
    """
    import jax.numpy as jnp

    from jkatana.light.envmap import EnvMap
    from jkatana.light.sun import split_compact_sources
    from jkatana.render.renderer import load_environment, rotation_y

    if scene.environment.type == "constant":
        return None, []
    grid = scene.spectral.grid
    radiance = np.asarray(load_environment(scene, grid), np.float64)
    caps = []
    if split:
        parts = split_compact_sources(EnvMap(jnp.asarray(radiance, jnp.float32), grid))
        if parts.caps:
            radiance = np.asarray(parts.remainder.radiance, np.float64)
            to_world = rotation_y(scene.environment.rotation_deg).T  # jkatana looks the map up at R·d
            for cap in parts.caps:
                d = to_world @ np.asarray(cap.direction, np.float64)
                caps.append(CapLight(tuple(float(x) for x in d / np.linalg.norm(d)), float(cap.radius),
                                     np.asarray(cap.radiance, np.float64), np.asarray(grid.wavelengths, np.float64)))
    return _to_rgb(radiance, grid), caps


def constant_radiance_rgb(scene) -> float:
    """A constant environment's radiance as the grey level of an RGB renderer (its luminance, same scale)."""
    from jkatana.spectral.colorimetry import xyz_weights

    grid = scene.spectral.grid
    return float(scene.environment.radiance * xyz_weights(grid)[:, 1].sum() / MITSUBA_Y_NORM)


def light_spectrum(light, wavelengths=EXPORT_WAVELENGTHS) -> np.ndarray:
    """A directional or point light's spectral irradiance (intensity) on ``wavelengths``, as jkatana shades it:
    the illuminant's relative power / 100 × intensity (:func:`jkatana.render.renderer.prepare`)."""
    from jkatana.spectral.colorimetry import illuminant
    from jkatana.spectral.grid import WavelengthGrid

    grid = WavelengthGrid(float(wavelengths[0]), float(wavelengths[-1]), float(wavelengths[1] - wavelengths[0]))
    return illuminant(light.spectrum, grid) / 100.0 * light.intensity


__all__ = ["EXPORT_WAVELENGTHS", "MITSUBA_Y_NORM", "RegionLobe", "CapLight", "Resolved", "resolve", "region_lobe",
           "environment_rgb", "constant_radiance_rgb", "light_spectrum"]

"""Scene content for the interactive path: blade, reflectance map, environments, cameras.

The built-in scene is the project's blade (:func:`jkatana.shape.katana.default_blade`:
Y up, blade along +X, edge toward −Y, flats facing ±Z; UV u along the blade, v
across from mune 0 to ha 1) with its reflectance map
(:func:`jkatana.maps.reflectance_map.default_map`); a render scene TOML
(:func:`from_render_scene`) is loaded by :mod:`jkatana.render`'s own loaders.

Built-in environments (equirectangular, Y up, see
:func:`jkatana.light.envmap.texel_directions_np`), spectral on the grid:

- ``"sky"`` (default): CIE daylight sky, 12000 K at the zenith to 6500 K at the
  horizon, a grey ground, and a soft 5500 K sun (3° radius) at 35° elevation.
- ``"sun"``: sun-dominated — a small (1.5°), bright 5000 K sun at 50° elevation
  over a dim sky.
- ``"studio"``: a dark room with two rectangular softboxes, one CIE D50 and one
  CIE illuminant A (tungsten), and a grey floor.

Spectra are CIE illuminants from :func:`jkatana.spectral.illuminant`,
normalised so that a radiance of 1 has luminance Y = 1 (eq. 6 weights).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import trimesh

from jkatana.errors import InputError
from jkatana.interactive.lobe_tables import PAPER_LOBES, region_lobes
from jkatana.light.envmap import texel_directions_np
from jkatana.maps.reflectance_map import default_map
from jkatana.render.film import film_weights
from jkatana.shape.katana import default_blade
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid
from jkatana.spectral.colorimetry import illuminant

ENVIRONMENTS = ("sky", "sun", "studio")


def _unit_y(spectrum: np.ndarray, grid: WavelengthGrid) -> np.ndarray:
    return spectrum / float(spectrum @ film_weights(grid)[:, 1])


def _dir(elev_deg: float, azim_deg: float) -> np.ndarray:
    """Direction from elevation above the horizon and azimuth clockwise from −Z (north) toward +X (east)."""
    e, a = np.deg2rad(elev_deg), np.deg2rad(azim_deg)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), -np.cos(e) * np.cos(a)])


def _disc(d: np.ndarray, centre: np.ndarray, radius_deg: float, soft_deg: float) -> np.ndarray:
    ang = np.rad2deg(np.arccos(np.clip(d @ centre, -1.0, 1.0)))
    return np.clip((radius_deg + soft_deg - ang) / (2 * soft_deg), 0.0, 1.0)


def environment(name: str = "sky", grid: WavelengthGrid = DEFAULT_GRID, height: int = 128) -> np.ndarray:
    """A built-in spectral environment ``(height, 2·height, wl)`` (see the module docstring)."""
    if name not in ENVIRONMENTS:
        raise InputError(f"unknown environment {name!r}; built-in: {', '.join(ENVIRONMENTS)}", field="environment")
    d = texel_directions_np(height, 2 * height)
    y = d[..., 1:2]
    up = np.clip(y, 0.0, 1.0)
    ground = (y < 0).astype(np.float64)
    d65 = _unit_y(illuminant("D65", grid), grid)
    if name in ("sky", "sun"):
        zen = _unit_y(illuminant(12000, grid), grid)
        hor = _unit_y(illuminant(6500, grid), grid)
        t = up ** 0.5
        level = 0.9 if name == "sky" else 0.35
        sky = level * ((1 - t) * hor * 1.2 + t * zen * 0.6)
        rad = sky * (1 - ground) + ground * 0.12 * level * d65 * (1 - 0.5 * np.clip(-y, 0, 1))
        if name == "sky":
            sun, r, soft, power, cct = _dir(35.0, 40.0), 3.0, 1.0, 12.0, 5500
        else:
            sun, r, soft, power, cct = _dir(50.0, -30.0), 1.5, 0.75, 120.0, 5000
        rad = rad + _disc(d, sun, r, soft)[..., None] * power * _unit_y(illuminant(cct, grid), grid)
        return rad
    # studio
    rad = 0.02 * np.ones_like(y) * d65 + ground * 0.15 * d65
    d50 = _unit_y(illuminant(5000, grid), grid)
    tung = _unit_y(illuminant("A", grid), grid)
    for (elev, az, w_deg, h_deg, spec, power) in ((25.0, -50.0, 30.0, 40.0, d50, 4.0),
                                                  (15.0, 70.0, 12.0, 50.0, tung, 2.5)):
        elev_d = np.rad2deg(np.arcsin(np.clip(y[..., 0], -1, 1)))
        az_d = np.rad2deg(np.arctan2(d[..., 0], -d[..., 2]))
        daz = (az_d - az + 180.0) % 360.0 - 180.0
        box = ((np.abs(daz) < w_deg / 2) & (np.abs(elev_d - elev) < h_deg / 2)).astype(np.float64)
        rad = rad + box[..., None] * power * spec
    return rad


# ----------------------------------------------------------------------------- blade and map


@functools.lru_cache(maxsize=2)
def blade() -> trimesh.Trimesh:
    """The built-in blade (:func:`jkatana.shape.katana.default_blade`), cached for the viewer's session."""
    return default_blade()


@dataclasses.dataclass(frozen=True)
class LobeMaps:
    """The three channels the GL path shades with: blend weight and lobe widths, ``(H, W)`` each;
    row 0 is v = 0 (the mune). The scale factors χ, β of :class:`jkatana.maps.ReflectanceMap` are
    not needed: the interactive path renders normalised lobes."""

    w: np.ndarray
    mu0: np.ndarray
    mu1: np.ndarray

    def stacked(self) -> np.ndarray:
        return np.stack([self.w, self.mu0, self.mu1], -1).astype(np.float64)


@functools.lru_cache(maxsize=2)
def reflectance_map() -> LobeMaps:
    """The built-in blade's map (:func:`jkatana.maps.reflectance_map.default_map`)."""
    m = default_map()
    return LobeMaps(w=np.asarray(m.w, np.float64), mu0=np.asarray(m.mu0, np.float64),
                    mu1=np.asarray(m.mu1, np.float64))


# ----------------------------------------------------------------------------- cameras


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world pose (OpenGL convention: the camera looks along its −Z, +Y up): the offline
    camera's own frame (:meth:`jkatana.render.camera.Camera.pose`), so both paths aim alike."""
    from jkatana.render.camera import Camera

    def point(a):
        return tuple(float(x) for x in np.asarray(a, np.float64))

    return Camera(position=point(eye), look_at=point(target), up=point(up)).pose()


@dataclasses.dataclass(frozen=True)
class View:
    """A pinhole camera: pose (camera-to-world 4×4), vertical field of view (radians), image size."""

    pose: np.ndarray
    yfov: float
    width: int
    height: int


def orbit_views(mesh: trimesh.Trimesh, n: int, width: int = 800, height: int = 600,
                distance: float = 0.75, elevation_deg: float = 15.0, spread_deg: float = 50.0):
    """``n`` views on an arc in front of the omote (+Z) face, looking at the blade's centre."""
    c = mesh.bounds.mean(axis=0)
    az = np.linspace(-spread_deg, spread_deg, n) if n > 1 else np.zeros(1)
    e = np.deg2rad(elevation_deg)
    out = []
    for a in np.deg2rad(az):
        eye = c + distance * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
        out.append(View(look_at(eye, c), np.deg2rad(50.0), width, height))
    return out


#: Direction of each built-in environment's key light (sun or the D50 softbox).
KEY_LIGHT = {"sky": _dir(35.0, 40.0), "sun": _dir(50.0, -30.0), "studio": _dir(25.0, -50.0)}


def glint_view(mesh: trimesh.Trimesh, light_dir, width: int = 800, height: int = 600,
               distance: float = 0.35) -> View:
    """A camera in the mirror direction of ``light_dir`` off the flat that faces it: the key light's
    glint lies on the blade's middle (the appraiser's "catching the light")."""
    light_dir = np.asarray(light_dir, np.float64)
    n = np.array([0.0, 0.0, 1.0 if light_dir[2] >= 0 else -1.0])
    v = 2 * (n @ light_dir) * n - light_dir
    target = np.array([0.35, mesh.bounds.mean(axis=0)[1], 0.0])
    return View(look_at(target + distance * v, target), np.deg2rad(40.0), width, height)


def closeup_view(mesh: trimesh.Trimesh, width: int = 800, height: int = 600) -> View:
    """A close-up in which the flat near the hamon fills the frame (as appraisers look)."""
    lo, hi = mesh.bounds
    target = np.array([0.45 * hi[0], 0.5 * (lo[1] + hi[1]), 0.0])
    eye = target + np.array([0.0, 0.004, 0.045])
    return View(look_at(eye, target), np.deg2rad(40.0), width, height)


# ----------------------------------------------------------------------------- what the viewer shows


@dataclasses.dataclass
class InteractiveScene:
    """Everything the interactive path needs, from a scene TOML or the built-in default.

    - `mesh` (trimesh with UVs), `refl_map` ``(H, W, 3)`` (w, μ0, μ1), `radiance` ``(H, W, wl)`` on `grid`;
    - `view`: the initial camera; `target`: orbit centre; `exposure`, `colourspace`, `transfer`;
    - `env_rotation` (radians about +Y); `source`: optical constants; `name`;
    - `lobes`: the regions' lobe families (hiraji, hamon) the bake's tables are computed for
      (:func:`jkatana.interactive.lobe_tables.region_lobes`; default the paper's).
    - `env_rows`: a map too large for its whole spectra (:func:`jkatana.render.memory.environment_route`) as a
      :class:`~jkatana.light.streaming.RowSource` the bake streams (`radiance` is then None), else None.
    """

    mesh: trimesh.Trimesh
    refl_map: np.ndarray
    radiance: np.ndarray | None
    grid: WavelengthGrid
    view: View
    target: np.ndarray
    exposure: float = 1.0
    colourspace: str = "sRGB"
    transfer: object = None
    env_rotation: float = 0.0
    source: str = "Fe-Johnson"
    name: str = "default"
    lobes: tuple = PAPER_LOBES
    env_rows: object = None

    def exposure_radiance(self) -> np.ndarray:
        """Spectra to guess the exposure from (:func:`jkatana.interactive.exposure.auto_exposure`): `radiance`,
        or for a map read in row blocks the exact spectra of a regular subsample of its texels."""
        if self.radiance is not None:
            return self.radiance
        from jkatana.render.streamed import subsample

        return self.env_rows.texels(*subsample(self.env_rows.height, self.env_rows.width))

    def orbit(self, n: int) -> list[View]:
        """``n`` views turning about the vertical axis through `target` (full turn split evenly)."""
        out = []
        for k in range(n):
            a = 2 * np.pi * k / max(n, 1)
            c, s = np.cos(a), np.sin(a)
            Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
            pose = self.view.pose.copy()
            pose[:3, :3] = Ry @ pose[:3, :3]
            pose[:3, 3] = self.target + Ry @ (pose[:3, 3] - self.target)
            out.append(View(pose, self.view.yfov, self.view.width, self.view.height))
        return out


def demo_view(width: int = 800, height: int = 600) -> View:
    """The demo camera of :data:`jkatana.render.scenefile.DEMO_SCENE` (without its roll): looking up at the
    omote flat near the hamon from 0.28 m (target (0.45, −0.022, 0), azimuth 20°, elevation −40°, fov 30°)."""
    target = np.array([0.45, -0.022, 0.0])
    az, el = np.deg2rad(20.0), np.deg2rad(-40.0)
    eye = target + 0.28 * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    return View(look_at(eye, target), np.deg2rad(30.0), width, height)


def default_scene(env: str = "sky", width: int = 800, height: int = 600) -> InteractiveScene:
    """The built-in scene: default blade and map, a built-in environment, the demo camera."""
    mesh = blade()
    return InteractiveScene(mesh=mesh, refl_map=reflectance_map().stacked(), radiance=environment(env),
                            grid=DEFAULT_GRID, view=demo_view(width, height), target=np.array([0.45, -0.022, 0.0]),
                            name=f"default-{env}")


def from_render_scene(path) -> InteractiveScene:
    """Load a :mod:`jkatana.render` scene TOML (geometry, map, environment, camera, film, spectral grid)."""
    from jkatana.render.renderer import camera_for, load_environment, load_geometry, load_material
    from jkatana.render.scenefile import load_scene

    sc = load_scene(path)
    grid = sc.spectral.grid
    geometry = load_geometry(sc)
    if not isinstance(geometry, trimesh.Trimesh):
        raise InputError("the interactive viewer needs a mesh (not an analytic sphere)", path=str(path),
                         field="geometry")
    maps, _, _, lobes = load_material(sc, geometry)
    cam = camera_for(sc)
    view = View(look_at(cam.position, cam.look_at, cam.up), np.deg2rad(cam.fov_deg), cam.width, cam.height)
    film = sc.film
    from jkatana.render.memory import environment_route

    rows = None
    if environment_route(sc.environment, grid.size, interactive=True) == "streamed":
        from jkatana.light.streaming import row_source

        e = sc.environment
        rows = row_source(e.path, grid, e.upsampling, e.scale, e.colourspace)
    return InteractiveScene(
        mesh=geometry, refl_map=np.asarray(maps, np.float64), env_rows=rows,
        radiance=None if rows is not None else np.asarray(load_environment(sc, grid), np.float64), grid=grid, view=view,
        target=np.asarray(cam.look_at, np.float64),
        exposure=float("nan") if film.exposure == "auto" else float(film.exposure),
        colourspace=film.colourspace, transfer=film.transfer,
        env_rotation=np.deg2rad(sc.environment.rotation_deg),
        source=sc.material.optical_constants, name=Path(path).stem, lobes=region_lobes(lobes))

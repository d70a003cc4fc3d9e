"""Scene files (TOML): reading, validation and writing of :class:`~jkatana.render.scene.Scene`.

Every error names its field. A complete example (every key optional except where noted; paths are
relative to the scene file)::

    [geometry]
    mesh = "builtin:katana"          # or a mesh file trimesh reads (PLY/GLB/OBJ with UVs)
    # sphere = { center = [0, 0, 0], radius = 1.0 }   # instead of a mesh (validation scenes)

    [material]
    map = "builtin"                  # or a reflectance-map EXR (jkatana map); or omit and give w/mu0/mu1
    # w = 1.0                        # uniform map (with mu0, mu1 in radians)
    hiraji = "hiraji.json"           # optional: jkatana fit parameter files of any lobe (the paper's,
    hamon = "hamon.json"             #   beckmann, ggx, gtr, two-lobe): their lobe and width (and
                                     #   scale) replace the map's for that region; other lobes than
                                     #   the paper's render in every mode but the paper's two, and in `jkatana view`
    optical_constants = "Fe-Johnson" # shipped name or a refractiveindex.info YAML path
    # calibration = 1.0e5            # K: camera units per unit source radiance → calibrated χ, β;
                                     # omitted → normalised lobes (perfect mirror as μ → 0)

    [environment]
    type = "sky"                     # "sky" (Hosek–Wilkie), "exr"/"hdr" (file), "constant" (grey)
    elevation_deg = 30.0             # sky: sun position, turbidity, ground albedo, map resolution
    azimuth_deg = 180.0
    turbidity = 3.0
    albedo = 0.1
    resolution = [256, 512]
    # path = "sky.exr"; upsampling = "Jakob 2019"; scale = 1.0   (file)
    # radiance = 1.0                                              (constant)
    rotation_deg = 0.0               # rotate the environment about +Y: + moves features clockwise seen
                                     # from above (compass azimuth a → a + rotation_deg; README picture)

    [[lights]]                       # optional, any number
    type = "point"                   # or "directional"
    position = [0.3, 0.5, 0.4]       # point: metres; directional: `direction` towards the light
    spectrum = "D65"                 # CIE illuminant name or a CCT in K
    intensity = 1.0                  # scales the spectrum (W sr⁻¹ nm⁻¹ at 560 nm per 100 units)

    [[occluders]]                    # optional, any number: geometry that blocks light (a stand,
    box = [0.1, 0.4, 0.1]            #   a second blade): box extents (m), or sphere = radius (m),
    center = [0.3, 0.0, 0.2]         #   or mesh = "stand.ply" (with scale = 1.0); center translates it
                                     # Occluders are black: they hide what is behind them from the
                                     # camera and shadow the environment and lights (visibility rays
                                     # from every shaded point). No occluders → no visibility rays.

    [camera]
    type = "orbit"                   # or "lookat" (position, look_at, up)
    target = [0.45, -0.022, 0.0]
    distance = 0.3
    azimuth_deg = 20.0
    elevation_deg = -40.0
    roll_deg = 0.0
    fov_deg = 30.0                   # vertical
    resolution = [800, 600]          # width, height

    [spectral]
    start = 400.0                    # nm; the paper's 61-sample grid by default
    stop = 700.0
    step = 5.0

    [render]
    mode = "reference"               # reference | paper | prefiltered | lowrank | paper-published;
                                     # prefiltered, paper, lowrank split a compact sun off as a cap light;
                                     # paper-published = the paper's 30 jittered lobe rays on the whole
                                     # map, as published: misses compact bright sources (a sun's glint)
    samples = 64
    rank = 3                         # lowrank mode
    seed = 0
    precision = "float32"            # or "float64" (validation)
    split_sun = "auto"               # true | false | "auto" (the mode's default: split in prefiltered, paper,
                                     # lowrank); reference + true samples each cap on its own by MIS: less
                                     # noise under a real sun (see the README)
    env_window = false               # or k (e.g. 2): the MIS modes' environment samples inside the cone
                                     # 2 atan(k mu) about the mirror direction; less noise on maps without
                                     # a compact source left in them, heavy-tailed where one is

    [film]
    colourspace = "sRGB"
    transfer = "sRGB"                # a colourspace name, "linear", or a gamma number
    exposure = "auto"                # or a number multiplying XYZ before display

    [output]
    directory = "out"
    name = "frame"
    spectral = false                 # also write a spectral EXR (Fichet et al. 2021 layout)

Every section is a frozen dataclass of :mod:`jkatana.render.scene`, validated once by
:func:`scene_from_dict`: types are strict (a string is not a boolean, a float is not an integer),
numbers finite, ranges and sizes bounded so that a scene cannot ask for more memory than a render can
hold (:data:`~jkatana.render.scene.LIMITS`). :func:`scene_to_toml` writes the validated scene back as
TOML (defaults filled in, paths resolved); reading that text gives the same scene.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import tomli_w

from jkatana.errors import InputError
from jkatana.render.integrators import integrator_for
from jkatana.render.scene import (ENV_TYPES, LIMITS, RENDER_MODES, WAVELENGTH_RANGE, CameraSpec, EnvironmentSpec, FilmSpec,
                                  GeometrySpec, LightSpec, MaterialSpec, OccluderSpec, OutputSpec, RenderSpec, Scene, SpectralSpec, UniformSpec)

SECTIONS = ("scene", "geometry", "material", "environment", "lights", "occluders", "camera", "spectral",
            "render", "film", "output")


class _Section:
    """Typed access to a TOML table; errors name ``section.key`` (and the file)."""

    def __init__(self, name: str, table: Any, path: Path | None):
        if not isinstance(table, dict):
            raise InputError(f"must be a table, got {type(table).__name__}", path=path, field=name)
        self.name, self.t, self.path, self.used = name, table, path, set()

    def err(self, key, msg):
        return InputError(msg, path=self.path, field=f"{self.name}.{key}")

    def get(self, key, default=None):
        self.used.add(key)
        return self.t.get(key, default)

    def number(self, key, default=None, *, lo=None, hi=None, positive=False, open_range=None):
        """A finite real (TOML integer or float; never a boolean), optionally bounded."""
        v = self.get(key, default)
        if v is None:
            raise self.err(key, "is required")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, f"must be a finite number, got {v!r}")
        if positive and not v > 0:
            raise self.err(key, f"must be > 0, got {v!r}")
        if lo is not None and v < lo or hi is not None and v > hi:
            raise self.err(key, f"must lie in [{lo}, {hi}], got {v!r}")
        if open_range is not None and not open_range[0] < v < open_range[1]:
            raise self.err(key, f"must lie in ({open_range[0]}, {open_range[1]}), got {v!r}")
        return float(v)

    def integer(self, key, default, *, lo, hi):
        """A TOML integer (not a float, not a boolean) in ``[lo, hi]``."""
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"must be an integer, got {v!r}")
        if not lo <= v <= hi:
            raise self.err(key, f"must lie in [{lo}, {hi}], got {v!r}")
        return int(v)

    def boolean(self, key, default):
        v = self.get(key, default)
        if not isinstance(v, bool):
            raise self.err(key, f"must be true or false, got {v!r}")
        return v

    def vector(self, key, n, default=None):
        v = self.get(key, default)
        if v is None:
            raise self.err(key, "is required")
        if (not isinstance(v, (list, tuple)) or len(v) != n
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
            raise self.err(key, f"must be a list of {n} finite numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def string(self, key, default=None, choices=None):
        v = self.get(key, default)
        if v is None:
            raise self.err(key, "is required")
        if not isinstance(v, str):
            raise self.err(key, f"must be a string, got {v!r}")
        if choices is not None and v.lower() not in choices:
            raise self.err(key, f"must be one of {list(choices)}, got {v!r}")
        return v.lower() if choices is not None else v

    def file(self, key, default=None, *, builtin=()):
        v = self.string(key, default)
        if v in builtin:
            return v
        p = Path(v).expanduser()
        if not p.is_absolute() and self.path is not None:
            p = self.path.parent / p
        if not p.is_file():
            raise InputError("file not found", path=p, field=f"{self.name}.{key}")
        return p

    def resolution(self, key, default, *, hi):
        """Two positive integers, each at most ``hi``."""
        v = self.get(key, list(default))
        if (not isinstance(v, (list, tuple)) or len(v) != 2
                or not all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
            raise self.err(key, f"must be two integers, got {v!r}")
        if min(v) < 1:
            raise self.err(key, f"zero-area image {list(v)}: both sizes must be ≥ 1")
        if max(v) > hi:
            raise self.err(key, f"must be at most {hi} per side, got {list(v)}")
        return (int(v[0]), int(v[1]))

    def check_unknown(self):
        unknown = sorted(set(self.t) - self.used)
        if unknown:
            raise self.err(unknown[0], f"unknown key (known: {sorted(self.used)})")


def scene_to_toml(scene: Scene) -> str:
    """The validated scene as TOML text, defaults filled in and paths absolute (stored with every output;
    :func:`scene_from_dict` of its parsed text gives the same scene)."""
    return tomli_w.dumps(scene.to_dict())


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene TOML file (see the module docstring for the schema)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("scene file not found", path=path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"malformed TOML ({err})", path=path) from None
    except UnicodeDecodeError as err:
        raise InputError(f"not a text file ({err.reason})", path=path) from None
    return scene_from_dict(raw, path)


def scene_from_dict(raw: dict, path: Path | None = None) -> Scene:
    """Validate a scene given as a dict (the parsed TOML); ``path`` anchors relative file names."""
    if not isinstance(raw, dict):
        raise InputError("a scene must be a table", path=path)
    for key in raw:
        if key not in SECTIONS:
            raise InputError(f"unknown section (known: {list(SECTIONS)})", path=path, field=key)
    if not isinstance(raw.get("scene", {}), dict):
        raise InputError("must be a table", path=path, field="scene")
    spectral = _spectral(raw, path)
    render = _render(raw, path, spectral)
    environment = _environment(raw, path, spectral)
    if integrator_for(render.mode).low_rank and environment.resolution is not None:
        texels = environment.resolution[0] * environment.resolution[1]
        if render.rank > texels:
            raise InputError(f"must be at most the environment's {texels} texels in lowrank mode, got {render.rank}",
                             path=path, field="render.rank")
    return Scene(path, _geometry(raw, path), _material(raw, path), environment, _lights(raw, path, spectral),
                 _camera(raw, path), spectral, render, _film(raw, path), _output(raw, path),
                 _occluders(raw.get("occluders", []), path))


def _geometry(raw, path) -> GeometrySpec:
    g = _Section("geometry", raw.get("geometry", {}), path)
    if "sphere" in g.t:
        s = _Section("geometry.sphere", g.get("sphere"), path)
        geometry = GeometrySpec("sphere", center=s.vector("center", 3, [0.0, 0.0, 0.0]),
                            radius=s.number("radius", 1.0, positive=True))
        s.check_unknown()
    else:
        geometry = GeometrySpec("mesh", mesh=g.file("mesh", "builtin:katana", builtin=("builtin:katana",)))
    g.check_unknown()
    return geometry


def _material(raw, path) -> MaterialSpec:
    m = _Section("material", raw.get("material", {}), path)
    oc = m.string("optical_constants", "Fe-Johnson")
    uniform, mapfile = None, None
    if any(k in m.t for k in ("w", "mu0", "mu1")) and "map" not in m.t:
        from jkatana.models.bounds import width

        # mu1 a width > 0 (jkatana.models.bounds) from 1e-4; mu0 may be 0: the hiraji as a perfect mirror
        # (Plan.mirror below MIRROR_MU), the normalised Gaussian lobe's limit as mu -> 0; both at most 1.5 rad
        uniform = UniformSpec(w=m.number("w", 1.0, lo=0.0, hi=1.0),
                          mu0=m.number("mu0", 0.05, lo=0.0, hi=1.5),
                          mu1=width(m.number("mu1", 0.05, lo=1e-4, hi=1.5), "material.mu1", path))
    else:
        mapfile = m.file("map", "builtin", builtin=("builtin",))
    regions = {region: m.file(region) if region in m.t else None for region in ("hiraji", "hamon")}
    calibration = m.number("calibration", positive=True) if "calibration" in m.t else None
    m.check_unknown()
    if oc.endswith((".yml", ".yaml")):
        p = Path(oc) if Path(oc).is_absolute() or path is None else path.parent / oc
        if not p.is_file():
            raise InputError("file not found", path=p, field="material.optical_constants")
        oc = str(p)
    return MaterialSpec(oc, mapfile, uniform, regions["hiraji"], regions["hamon"], calibration)


def _environment(raw, path, spectral: SpectralSpec) -> EnvironmentSpec:
    e = _Section("environment", raw.get("environment", {}), path)
    etype = e.string("type", "sky", choices=ENV_TYPES)
    rotation = e.number("rotation_deg", 0.0)
    if etype == "sky":
        env = EnvironmentSpec(etype, rotation, elevation_deg=e.number("elevation_deg", 30.0, lo=0.0, hi=90.0),
                          azimuth_deg=e.number("azimuth_deg", 180.0),
                          turbidity=e.number("turbidity", 3.0, lo=1.0, hi=10.0),
                          albedo=e.number("albedo", 0.1, lo=0.0, hi=1.0),
                          sun=e.boolean("sun", True),
                          resolution=e.resolution("resolution", (256, 512), hi=LIMITS["env_side"]))
    elif etype in ("exr", "hdr"):
        from jkatana.light.upsampling import UPSAMPLING_METHODS

        env = EnvironmentSpec(etype, rotation, path=e.file("path"),
                          upsampling=e.string("upsampling", "Jakob 2019"),
                          scale=e.number("scale", 1.0, positive=True),
                          colourspace=e.string("colourspace", "sRGB"))
        if env.upsampling not in UPSAMPLING_METHODS:
            raise e.err("upsampling", f"must be one of {sorted(UPSAMPLING_METHODS)}, got {env.upsampling!r}")
        _check_colourspace(env.colourspace, path, "environment.colourspace")
    else:
        env = EnvironmentSpec(etype, rotation, radiance=e.number("radiance", 1.0, positive=True),
                          resolution=e.resolution("resolution", (16, 32), hi=LIMITS["env_side"]))
    e.check_unknown()
    if env.resolution is not None:
        values = env.resolution[0] * env.resolution[1] * spectral.grid.size
        if values > LIMITS["env_values"]:
            raise e.err("resolution", f"{list(env.resolution)} texels × {spectral.grid.size} wavelengths = "
                                      f"{values * 8 / 2**30:.1f} GiB of float64 radiance; at most "
                                      f"{LIMITS['env_values'] * 8 / 2**30:.0f} GiB")
    return env


def _lights(raw, path, spectral: SpectralSpec) -> tuple[LightSpec, ...]:
    from jkatana.spectral.colorimetry import illuminant

    raw_lights = raw.get("lights", [])
    if not isinstance(raw_lights, list):
        raise InputError("must be an array of tables ([[lights]])", path=path, field="lights")
    lights = []
    for i, lt in enumerate(raw_lights):
        s = _Section(f"lights[{i}]", lt, path)
        kind = s.string("type", "point", choices=("point", "directional"))
        vec = s.vector("position" if kind == "point" else "direction", 3)
        if kind == "directional" and math.hypot(*vec) == 0:
            raise s.err("direction", "must not be the zero vector")
        spec = s.get("spectrum", "D65")
        if isinstance(spec, bool) or not isinstance(spec, (str, int, float)):
            raise s.err("spectrum", f"must be an illuminant name or a CCT, got {spec!r}")
        spec = spec if isinstance(spec, str) else float(spec)
        try:
            illuminant(spec, spectral.grid)
        except InputError as err:
            raise s.err("spectrum", str(err).split(": ", 1)[-1]) from None
        lights.append(LightSpec(kind, vec, spec, s.number("intensity", 1.0, positive=True)))
        s.check_unknown()
    return tuple(lights)


def _camera(raw, path) -> CameraSpec:
    c = _Section("camera", raw.get("camera", {}), path)
    ctype = c.string("type", "orbit", choices=("orbit", "lookat"))
    common = dict(fov_deg=c.number("fov_deg", 30.0, open_range=(0.0, 180.0)),
                  resolution=c.resolution("resolution", (800, 600), hi=LIMITS["camera_side"]),
                  roll_deg=c.number("roll_deg", 0.0))
    if ctype == "orbit":
        cam = CameraSpec(ctype, **common, target=c.vector("target", 3, [0.45, -0.022, 0.0]),
                     distance=c.number("distance", 0.3, positive=True),
                     azimuth_deg=c.number("azimuth_deg", 20.0),
                     elevation_deg=c.number("elevation_deg", -40.0, lo=-89.9, hi=89.9))
    else:
        cam = CameraSpec(ctype, **common, position=c.vector("position", 3), look_at=c.vector("look_at", 3),
                     up=c.vector("up", 3, [0.0, 1.0, 0.0]))
    c.check_unknown()
    return cam


def _spectral(raw, path) -> SpectralSpec:
    sp = _Section("spectral", raw.get("spectral", {}), path)
    lo, hi = WAVELENGTH_RANGE
    s = SpectralSpec(sp.number("start", 400.0, lo=lo, hi=hi), sp.number("stop", 700.0, lo=lo, hi=hi),
                 sp.number("step", 5.0, positive=True))
    sp.check_unknown()
    if s.stop <= s.start:
        raise sp.err("stop", "must be greater than spectral.start")
    count = (s.stop - s.start) / s.step
    if count + 1 > LIMITS["wavelengths"] + 1e-9:
        raise sp.err("step", f"{count + 1:.0f} wavelengths; at most {LIMITS['wavelengths']} (1 nm over "
                             f"{lo:g}–{hi:g} nm)")
    try:
        s.grid
    except InputError as err:
        raise sp.err("step", str(err).split(": ", 1)[-1]) from None
    return s


def _render(raw, path, spectral: SpectralSpec) -> RenderSpec:
    r = _Section("render", raw.get("render", {}), path)
    render = RenderSpec(mode=r.string("mode", "reference", choices=RENDER_MODES),
                    samples=r.integer("samples", 64, lo=1, hi=LIMITS["samples"]),
                    rank=r.integer("rank", 3, lo=1, hi=spectral.grid.size),
                    seed=r.integer("seed", 0, lo=0, hi=LIMITS["seed"]),
                    precision=r.string("precision", "float32", choices=("float32", "float64")),
                    chunk=r.integer("chunk", 16384, lo=256, hi=LIMITS["chunk"]),
                    split_sun=_split_sun(r), env_window=_env_window(r))
    r.check_unknown()
    if integrator_for(render.mode).whole_map and render.split_sun:
        raise r.err("split_sun", "the paper-published mode shades the whole map, as published: no sun split")
    return render


def _split_sun(r: _Section) -> bool | None:
    """``render.split_sun``: ``true``/``false``, or ``"auto"`` (absent: the mode's default) → ``None``."""
    v = r.get("split_sun", "auto")
    if isinstance(v, str) and v.lower() == "auto":
        return None
    if not isinstance(v, bool):
        raise r.err("split_sun", f"must be true, false or \"auto\", got {v!r}")
    return v


def _env_window(r: _Section) -> float | None:
    """``render.env_window``: ``false``/absent (the whole map) → ``None``, or the window's ``k`` in (0, 100]."""
    v = r.get("env_window", False)
    if v is False:
        return None
    return r.number("env_window", lo=0.0, hi=100.0, positive=True)


def _check_colourspace(name, path, field):
    from jkatana.spectral.colorimetry import colourspace

    try:
        colourspace(name)
    except InputError as err:
        raise InputError(str(err).split(": ", 1)[-1], path=path, field=field) from None


def _film(raw, path) -> FilmSpec:
    f = _Section("film", raw.get("film", {}), path)
    colourspace = f.string("colourspace", "sRGB")
    transfer = f.get("transfer", None)
    if transfer is not None and not (isinstance(transfer, str) or
                                     (isinstance(transfer, (int, float)) and not isinstance(transfer, bool)
                                      and math.isfinite(transfer) and transfer > 0)):
        raise f.err("transfer", f"must be a colourspace name, 'linear' or a gamma > 0, got {transfer!r}")
    exposure = f.get("exposure", "auto")
    if not (exposure == "auto" or (isinstance(exposure, (int, float)) and not isinstance(exposure, bool)
                                   and math.isfinite(exposure) and exposure > 0)):
        raise f.err("exposure", f"must be 'auto' or a number > 0, got {exposure!r}")
    f.check_unknown()
    for key, name in (("colourspace", colourspace), ("transfer", transfer)):
        if isinstance(name, str) and name.lower() != "linear":
            _check_colourspace(name, path, f"film.{key}")
    return FilmSpec(colourspace, transfer if isinstance(transfer, str) or transfer is None else float(transfer),
                exposure if exposure == "auto" else float(exposure))


def _output(raw, path) -> OutputSpec:
    o = _Section("output", raw.get("output", {}), path)
    out_dir = Path(o.string("directory", "out")).expanduser()
    if not out_dir.is_absolute() and path is not None:
        out_dir = path.parent / out_dir
    output = OutputSpec(out_dir, o.string("name", "frame"), o.boolean("spectral", False))
    if "/" in output.name or "\\" in output.name or output.name.strip(".") == "" or "\0" in output.name:
        raise o.err("name", f"must be a plain file stem, got {output.name!r}")
    o.check_unknown()
    return output


def _occluders(raw_occ, path) -> tuple[OccluderSpec, ...]:
    """``[[occluders]]``: each exactly one of ``box`` (extents), ``sphere`` (radius), ``mesh`` (file)."""
    if not isinstance(raw_occ, list):
        raise InputError("must be an array of tables ([[occluders]])", path=path, field="occluders")
    out = []
    for i, oc in enumerate(raw_occ):
        s = _Section(f"occluders[{i}]", oc, path)
        kinds = [k for k in ("box", "sphere", "mesh") if k in s.t]
        if len(kinds) != 1:
            raise InputError(f"needs exactly one of box, sphere, mesh (got {kinds or 'none'})", path=path,
                             field=f"occluders[{i}]")
        center = s.vector("center", 3, [0.0, 0.0, 0.0])
        if kinds[0] == "box":
            ext = s.vector("box", 3)
            if min(ext) <= 0:
                raise s.err("box", f"extents must be > 0, got {list(ext)}")
            occ = OccluderSpec("box", center, extents=ext)
        elif kinds[0] == "sphere":
            occ = OccluderSpec("sphere", center, radius=s.number("sphere", positive=True))
        else:
            occ = OccluderSpec("mesh", center, mesh=s.file("mesh"), scale=s.number("scale", 1.0, positive=True))
        s.check_unknown()
        out.append(occ)
    return tuple(out)


def default_scene() -> Scene:
    """The built-in demo scene: the built-in blade and map under the built-in sky."""
    return scene_from_dict(DEMO_SCENE)


#: The demo scene: the built-in blade's upper ~29 cm with the kissaki, on a diagonal (roll 26°),
#: seen from in front (+Z, the omote), 20° toward the tip and 32° below. The hiraji's normals tilt
#: 7–12° towards the edge (−Y), so from below the ji mirrors the sky 12–22° up and the hamon side
#: 6–14° up: a sky gradient across and along the flat (the cue that makes polished steel read as
#: a mirror), the shinogi-ji and mune a deeper blue. The sun (elevation 34°, compass azimuth 220°)
#: stands ≥ 0.16 rad (median 0.22 rad) in facet angle from the ji pixels' mirror directions: the
#: paper's μ0 = 0.05 rad lobe lets its tail through only as a white streak along the lower ji,
#: where that angle is smallest (~3 μ0), while the sun sits at ~1.4 μ1 (median 0.28 rad) of the
#: built-in hamon's wider lobe (μ1 ≈ 0.2 rad, see default_map), which therefore glows as a soft
#: warm band (with the sun switched off the hamon is no brighter than the ji).
#: tests/test_render_demo.py checks these angles. Exposure is automatic: the blade's mean displayed
#: luminance (clipped at white) is 0.35 (jkatana.render.film.scene_exposure, shared with `view`).
DEMO_SCENE: dict = {
    "geometry": {"mesh": "builtin:katana"},
    "material": {"map": "builtin", "optical_constants": "Fe-Johnson"},
    "environment": {"type": "sky", "elevation_deg": 34.0, "azimuth_deg": 220.0, "turbidity": 3.0,
                    "albedo": 0.1, "resolution": [256, 512]},
    "camera": {"type": "orbit", "target": [0.59, -0.025, 0.0], "distance": 0.33, "azimuth_deg": 20.0,
               "elevation_deg": -32.0, "roll_deg": 26.0, "fov_deg": 30.0, "resolution": [800, 600]},
    "render": {"mode": "reference", "samples": 64},
    "film": {"colourspace": "sRGB", "exposure": "auto"},
    "output": {"directory": "out/demo", "name": "demo"},
}

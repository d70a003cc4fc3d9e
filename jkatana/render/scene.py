"""Scene files (TOML): what to render and how. Validated; every error names its field.

A complete example (every key optional except where noted; paths are relative
to the scene file)::

    [geometry]
    mesh = "builtin:katana"          # or a mesh file trimesh reads (PLY/GLB/OBJ with UVs)
    # sphere = { center = [0, 0, 0], radius = 1.0 }   # instead of a mesh (validation scenes)

    [material]
    map = "builtin"                  # or a reflectance-map EXR (jkatana map); or omit and give w/mu0/mu1
    # w = 1.0                        # uniform map (with mu0, mu1 in radians)
    hiraji = "hiraji.json"           # optional: jkatana fit parameter files; their μ (and χ, β)
    hamon = "hamon.json"             #   replace the map's values for that region
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
    rotation_deg = 0.0               # rotate the environment about +Y

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
    mode = "reference"               # reference | paper | prefiltered | lowrank
    samples = 64
    rank = 3                         # lowrank mode
    seed = 0
    precision = "float32"            # or "float64" (validation)

    [film]
    colourspace = "sRGB"
    transfer = "sRGB"                # a colourspace name, "linear", or a gamma number
    exposure = "auto"                # or a number multiplying XYZ before display

    [output]
    directory = "out"
    name = "frame"
    spectral = false                 # also write a spectral EXR (Fichet et al. 2021 layout)
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

from jkatana.errors import InputError

SECTIONS = ("scene", "geometry", "material", "environment", "lights", "occluders", "camera", "spectral",
            "render", "film", "output")
ENV_TYPES = ("sky", "exr", "hdr", "constant")
RENDER_MODES = ("reference", "paper", "prefiltered", "lowrank")


@dataclasses.dataclass
class Scene:
    """A validated scene: plain values (paths resolved, nothing loaded yet)."""

    path: Path | None
    geometry: dict
    material: dict
    environment: dict
    lights: list
    camera: dict
    spectral: dict
    render: dict
    film: dict
    output: dict
    raw: dict = dataclasses.field(repr=False, default_factory=dict)
    occluders: list = dataclasses.field(default_factory=list)

    def to_toml_text(self) -> str:
        """The scene's raw TOML as a compact JSON string (stored with every output)."""
        import json

        return json.dumps(self.raw, default=str, sort_keys=True)


class _Section:
    """Typed access to a TOML table; errors name ``section.key`` (and the file)."""

    def __init__(self, name: str, table: Any, path: Path | None):
        if not isinstance(table, dict):
            raise InputError(f"must be a table, got {type(table).__name__}", path=path, field=name)
        self.name, self.t, self.path, self.used = name, table, path, set()

    def _err(self, key, msg):
        return InputError(msg, path=self.path, field=f"{self.name}.{key}")

    def get(self, key, default=None):
        self.used.add(key)
        return self.t.get(key, default)

    def number(self, key, default=None, *, lo=None, hi=None, positive=False, integer=False):
        v = self.get(key, default)
        if v is None:
            raise self._err(key, "is required")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self._err(key, f"must be a finite number, got {v!r}")
        if integer and int(v) != v:
            raise self._err(key, f"must be an integer, got {v!r}")
        if positive and not v > 0:
            raise self._err(key, f"must be > 0, got {v!r}")
        if lo is not None and v < lo or hi is not None and v > hi:
            raise self._err(key, f"must lie in [{lo}, {hi}], got {v!r}")
        return int(v) if integer else float(v)

    def vector(self, key, n, default=None):
        v = self.get(key, default)
        if v is None:
            raise self._err(key, "is required")
        if (not isinstance(v, (list, tuple)) or len(v) != n
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
            raise self._err(key, f"must be a list of {n} finite numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def string(self, key, default=None, choices=None):
        v = self.get(key, default)
        if v is None:
            raise self._err(key, "is required")
        if not isinstance(v, str):
            raise self._err(key, f"must be a string, got {v!r}")
        if choices is not None and v.lower() not in choices:
            raise self._err(key, f"must be one of {list(choices)}, got {v!r}")
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

    def check_unknown(self):
        unknown = sorted(set(self.t) - self.used)
        if unknown:
            raise self._err(unknown[0], f"unknown key (known: {sorted(self.used)})")


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene TOML file (see the module docstring for the schema)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("scene file not found", path=path)
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"malformed TOML ({err})", path=path) from None
    except UnicodeDecodeError as err:
        raise InputError(f"not a text file ({err.reason})", path=path) from None
    return scene_from_dict(raw, path)


def scene_from_dict(raw: dict, path: Path | None = None) -> Scene:
    """Validate a scene given as a dict (the parsed TOML)."""
    for key in raw:
        if key not in SECTIONS:
            raise InputError(f"unknown section (known: {list(SECTIONS)})", path=path, field=key)

    g = _Section("geometry", raw.get("geometry", {}), path)
    if "sphere" in g.t:
        s = _Section("geometry.sphere", g.get("sphere"), path)
        geometry = {"kind": "sphere", "center": s.vector("center", 3, [0.0, 0.0, 0.0]),
                    "radius": s.number("radius", 1.0, positive=True)}
        s.check_unknown()
    else:
        geometry = {"kind": "mesh", "mesh": g.file("mesh", "builtin:katana", builtin=("builtin:katana",))}
    g.check_unknown()

    m = _Section("material", raw.get("material", {}), path)
    material: dict = {"optical_constants": m.string("optical_constants", "Fe-Johnson")}
    if any(k in m.t for k in ("w", "mu0", "mu1")) and "map" not in m.t:
        material["map"] = None
        material["uniform"] = {"w": m.number("w", 1.0, lo=0.0, hi=1.0),
                               "mu0": m.number("mu0", 0.05, lo=0.0, hi=1.5),
                               "mu1": m.number("mu1", 0.05, lo=1e-4, hi=1.5)}
    else:
        material["map"] = m.file("map", "builtin", builtin=("builtin",))
    for region in ("hiraji", "hamon"):
        material[region] = m.file(region) if region in m.t else None
    material["calibration"] = m.number("calibration", positive=True) if "calibration" in m.t else None
    m.check_unknown()
    oc = material["optical_constants"]
    if oc.endswith((".yml", ".yaml")):
        p = Path(oc) if Path(oc).is_absolute() or path is None else path.parent / oc
        if not p.is_file():
            raise InputError("file not found", path=p, field="material.optical_constants")
        material["optical_constants"] = str(p)

    e = _Section("environment", raw.get("environment", {}), path)
    etype = e.string("type", "sky", choices=ENV_TYPES)
    environment: dict = {"type": etype, "rotation_deg": e.number("rotation_deg", 0.0)}
    if etype == "sky":
        environment.update(elevation_deg=e.number("elevation_deg", 30.0, lo=0.0, hi=90.0),
                           azimuth_deg=e.number("azimuth_deg", 180.0),
                           turbidity=e.number("turbidity", 3.0, lo=1.0, hi=10.0),
                           albedo=e.number("albedo", 0.1, lo=0.0, hi=1.0),
                           resolution=_resolution(e, "resolution", (256, 512)),
                           sun=bool(e.get("sun", True)))
    elif etype in ("exr", "hdr"):
        environment.update(path=e.file("path"), upsampling=e.string("upsampling", "Jakob 2019"),
                           scale=e.number("scale", 1.0, positive=True),
                           colourspace=e.string("colourspace", "sRGB"))
    else:
        environment.update(radiance=e.number("radiance", 1.0, positive=True),
                           resolution=_resolution(e, "resolution", (16, 32)))
    e.check_unknown()

    lights = []
    raw_lights = raw.get("lights", [])
    if not isinstance(raw_lights, list):
        raise InputError("must be an array of tables ([[lights]])", path=path, field="lights")
    for i, lt in enumerate(raw_lights):
        s = _Section(f"lights[{i}]", lt, path)
        kind = s.string("type", "point", choices=("point", "directional"))
        vec = s.vector("position" if kind == "point" else "direction", 3)
        if kind == "directional" and math.hypot(*vec) == 0:
            raise InputError("must not be the zero vector", path=path, field=f"lights[{i}].direction")
        spec = s.get("spectrum", "D65")
        if not isinstance(spec, (str, int, float)) or isinstance(spec, bool):
            raise InputError(f"must be an illuminant name or a CCT, got {spec!r}", path=path,
                             field=f"lights[{i}].spectrum")
        lights.append({"type": kind, "vector": vec, "spectrum": spec,
                       "intensity": s.number("intensity", 1.0, positive=True)})
        s.check_unknown()

    occluders = _occluders(raw.get("occluders", []), path)

    c = _Section("camera", raw.get("camera", {}), path)
    ctype = c.string("type", "orbit", choices=("orbit", "lookat"))
    camera: dict = {"type": ctype, "fov_deg": c.number("fov_deg", 30.0),
                    "resolution": _resolution(c, "resolution", (800, 600), allow_zero=True),
                    "roll_deg": c.number("roll_deg", 0.0)}
    if not 0 < camera["fov_deg"] < 180:
        raise InputError(f"must lie in (0, 180), got {camera['fov_deg']}", path=path, field="camera.fov_deg")
    if min(camera["resolution"]) < 1:
        raise InputError(f"zero-area image {camera['resolution']}", path=path, field="camera.resolution")
    if ctype == "orbit":
        camera.update(target=c.vector("target", 3, [0.45, -0.022, 0.0]),
                      distance=c.number("distance", 0.3, positive=True),
                      azimuth_deg=c.number("azimuth_deg", 20.0),
                      elevation_deg=c.number("elevation_deg", -40.0, lo=-89.9, hi=89.9))
    else:
        camera.update(position=c.vector("position", 3), look_at=c.vector("look_at", 3),
                      up=c.vector("up", 3, [0.0, 1.0, 0.0]))
    c.check_unknown()

    sp = _Section("spectral", raw.get("spectral", {}), path)
    spectral = {"start": sp.number("start", 400.0), "stop": sp.number("stop", 700.0),
                "step": sp.number("step", 5.0, positive=True)}
    if spectral["stop"] <= spectral["start"]:
        raise InputError("must be greater than spectral.start", path=path, field="spectral.stop")
    sp.check_unknown()

    r = _Section("render", raw.get("render", {}), path)
    render = {"mode": r.string("mode", "reference", choices=RENDER_MODES),
              "samples": r.number("samples", 64, integer=True, lo=1, hi=1 << 16),
              "rank": r.number("rank", 3, integer=True, lo=1, hi=64),
              "seed": r.number("seed", 0, integer=True, lo=0),
              "precision": r.string("precision", "float32", choices=("float32", "float64")),
              "chunk": r.number("chunk", 16384, integer=True, lo=256)}
    r.check_unknown()

    f = _Section("film", raw.get("film", {}), path)
    film = {"colourspace": f.string("colourspace", "sRGB")}
    transfer = f.get("transfer", None)
    if transfer is not None and not (isinstance(transfer, str) or
                                     (isinstance(transfer, (int, float)) and not isinstance(transfer, bool)
                                      and transfer > 0)):
        raise InputError(f"must be a colourspace name, 'linear' or a gamma > 0, got {transfer!r}",
                         path=path, field="film.transfer")
    film["transfer"] = transfer
    exposure = f.get("exposure", "auto")
    if not (exposure == "auto" or (isinstance(exposure, (int, float)) and not isinstance(exposure, bool)
                                   and exposure > 0)):
        raise InputError(f"must be 'auto' or a number > 0, got {exposure!r}", path=path, field="film.exposure")
    film["exposure"] = exposure
    f.check_unknown()
    from jkatana.spectral.colorimetry import colourspace as _cs

    for key, name in (("colourspace", film["colourspace"]), ("transfer", transfer)):
        if isinstance(name, str) and name.lower() != "linear":
            try:
                _cs(name)
            except InputError as err:
                raise InputError(str(err).split(": ", 1)[-1], path=path, field=f"film.{key}") from None

    o = _Section("output", raw.get("output", {}), path)
    out_dir = Path(o.string("directory", "out")).expanduser()
    if not out_dir.is_absolute() and path is not None:
        out_dir = path.parent / out_dir
    output = {"directory": out_dir, "name": o.string("name", "frame"), "spectral": bool(o.get("spectral", False))}
    if "/" in output["name"] or not output["name"]:
        raise InputError(f"must be a plain file stem, got {output['name']!r}", path=path, field="output.name")
    o.check_unknown()

    sc = raw.get("scene", {})
    if not isinstance(sc, dict):
        raise InputError("must be a table", path=path, field="scene")
    return Scene(path, geometry, material, environment, lights, camera, spectral, render, film, output, raw,
                 occluders=occluders)


def _occluders(raw_occ, path) -> list[dict]:
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
        spec: dict = {"kind": kinds[0], "center": s.vector("center", 3, [0.0, 0.0, 0.0])}
        if kinds[0] == "box":
            ext = s.vector("box", 3)
            if min(ext) <= 0:
                raise s._err("box", f"extents must be > 0, got {list(ext)}")
            spec["extents"] = ext
        elif kinds[0] == "sphere":
            spec["radius"] = s.number("sphere", positive=True)
        else:
            spec["mesh"] = s.file("mesh")
            spec["scale"] = s.number("scale", 1.0, positive=True)
        s.check_unknown()
        out.append(spec)
    return out


def _resolution(sec: _Section, key: str, default, allow_zero=False):
    v = sec.get(key, list(default))
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(x, int) and not isinstance(x, bool) for x in v) or min(v) < 0):
        raise sec._err(key, f"must be two non-negative integers, got {v!r}")
    if not allow_zero and min(v) < 1:
        raise sec._err(key, f"must be positive, got {v!r}")
    return (int(v[0]), int(v[1]))


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
#: tests/test_render_demo.py checks these angles. Exposure is automatic: the 75th percentile of
#: the blade pixels' Y maps to 0.6 (jkatana.render.renderer.exposure_for).
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

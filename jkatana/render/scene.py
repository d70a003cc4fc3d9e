"""The scene: what to render and how, as one typed, validated value.

Every section of a scene file is a frozen dataclass here, named ``*Spec`` so that the render-time objects
of the same idea (:class:`jkatana.render.environment.Environment`, :class:`jkatana.render.camera.Camera`, ...)
keep the plain names (:class:`GeometrySpec`,
:class:`MaterialSpec`, :class:`EnvironmentSpec`, :class:`LightSpec`, :class:`OccluderSpec`,
:class:`CameraSpec`, :class:`SpectralSpec`, :class:`RenderSpec`, :class:`FilmSpec`,
:class:`OutputSpec`), gathered in :class:`Scene`; ``to_dict`` gives each back in
the file's schema. Reading, validating and writing the TOML file (every error
naming its field) is :mod:`jkatana.render.scenefile`, whose
:func:`~jkatana.render.scenefile.load_scene`,
:func:`~jkatana.render.scenefile.scene_from_dict`,
:func:`~jkatana.render.scenefile.default_scene` and
:data:`~jkatana.render.scenefile.DEMO_SCENE` are also reachable here by name
(looked up on first use: this module does not import the reader, which
imports it).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from jkatana.io.limits import ENV_VALUES
from jkatana.render.integrators import INTEGRATORS
from jkatana.spectral.grid import MAX_BANDS, WAVELENGTH_RANGE, WavelengthGrid

ENV_TYPES = ("sky", "exr", "hdr", "constant")
RENDER_MODES = tuple(INTEGRATORS)

#: Upper bounds on what a scene may ask for. The camera and environment sides keep one frame's
#: buffers (G-buffer, XYZ, optional spectra) and the environment's float64 spectral radiance and
#: sampling tables within a few GiB; 1 nm over the CIE 1931 observer's 360–830 nm domain is the
#: finest grid the colour matching functions are tabulated on (CIE 015:2018).
LIMITS = {
    "camera_side": 8192,        # pixels per side
    "env_side": 4096,           # texels per side of a sky or constant environment
    "env_values": ENV_VALUES,   # texels × wavelengths of the environment (2 GiB as float64; jkatana.io.limits)
    "wavelengths": MAX_BANDS,   # 360–830 nm at 1 nm (jkatana.spectral.grid)
    "samples": 1 << 16,         # samples per pixel
    "chunk": 1 << 20,           # pixels shaded per device call
    "seed": (1 << 31) - 1,
}


def _plain(v):
    """A value as TOML writes it (paths as absolute strings, so that the text means the same files
    wherever it is read; tuples as arrays)."""
    if isinstance(v, Path):
        return str(v.absolute())
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _table(obj, *, skip=()) -> dict:
    """A section's schema table: its fields less ``skip`` and those that are ``None``."""
    return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)
            if f.name not in skip and getattr(obj, f.name) is not None}


Vec3 = tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class GeometrySpec:
    """What is rendered: a triangle mesh with UVs (``"builtin:katana"`` or a file), or an analytic sphere."""

    kind: str                    # "mesh" | "sphere"
    mesh: Path | str | None = None
    center: Vec3 | None = None   # sphere
    radius: float | None = None  # sphere

    def to_dict(self) -> dict:
        if self.kind == "sphere":
            return {"sphere": {"center": list(self.center), "radius": self.radius}}
        return {"mesh": _plain(self.mesh)}


@dataclasses.dataclass(frozen=True)
class UniformSpec:
    """A spatially uniform reflectance map: hamon weight ``w`` and lobe widths ``mu0``, ``mu1`` (rad)."""

    w: float
    mu0: float
    mu1: float


@dataclasses.dataclass(frozen=True)
class MaterialSpec:
    """The blade's reflectance: a map (or a uniform one), region parameter files, optical constants."""

    optical_constants: str
    map: Path | str | None          # "builtin", a map EXR, or None with `uniform`
    uniform: UniformSpec | None = None
    hiraji: Path | None = None
    hamon: Path | None = None
    calibration: float | None = None

    def to_dict(self) -> dict:
        d = _table(self, skip=("uniform",))
        if self.uniform is not None:
            d.update(dataclasses.asdict(self.uniform))
        return d


@dataclasses.dataclass(frozen=True)
class EnvironmentSpec:
    """Distant illumination: a Hosek–Wilkie sky, an HDR/EXR file, or a constant grey radiance.

    Only the fields of the chosen ``type`` are set; the others are ``None``.
    """

    type: str
    rotation_deg: float = 0.0
    elevation_deg: float | None = None   # sky
    azimuth_deg: float | None = None
    turbidity: float | None = None
    albedo: float | None = None
    sun: bool | None = None
    resolution: tuple[int, int] | None = None  # sky, constant: (rows, columns)
    path: Path | None = None             # exr/hdr
    upsampling: str | None = None
    scale: float | None = None
    colourspace: str | None = None
    radiance: float | None = None        # constant

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class LightSpec:
    """A point light (``vector`` = position, m) or a directional one (``vector`` = direction to the light)."""

    type: str
    vector: Vec3
    spectrum: str | float = "D65"
    intensity: float = 1.0

    def to_dict(self) -> dict:
        return {"type": self.type, "position" if self.type == "point" else "direction": list(self.vector),
                "spectrum": self.spectrum, "intensity": self.intensity}


@dataclasses.dataclass(frozen=True)
class OccluderSpec:
    """Black geometry that blocks light: a box (``extents``), a sphere (``radius``) or a mesh file."""

    kind: str                    # "box" | "sphere" | "mesh"
    center: Vec3 = (0.0, 0.0, 0.0)
    extents: Vec3 | None = None
    radius: float | None = None
    mesh: Path | None = None
    scale: float | None = None

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"center": list(self.center)}
        if self.kind == "box":
            d["box"] = list(self.extents)
        elif self.kind == "sphere":
            d["sphere"] = self.radius
        else:
            d.update(mesh=_plain(self.mesh), scale=self.scale)
        return d


@dataclasses.dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera: ``"orbit"`` about a target or ``"lookat"``; ``resolution`` is (width, height)."""

    type: str
    fov_deg: float
    resolution: tuple[int, int]
    roll_deg: float = 0.0
    target: Vec3 | None = None       # orbit
    distance: float | None = None
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    position: Vec3 | None = None     # lookat
    look_at: Vec3 | None = None
    up: Vec3 | None = None

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class SpectralSpec:
    """The wavelength grid (nm) every spectrum of the render is sampled on."""

    start: float = 400.0
    stop: float = 700.0
    step: float = 5.0

    @property
    def grid(self) -> WavelengthGrid:
        return WavelengthGrid(self.start, self.stop, self.step)

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class RenderSpec:
    """How to integrate: the mode, samples per pixel, low-rank environment rank, seed, precision, chunk,
    and two sampling choices: ``split_sun`` (compact bright sources split off as cap lights; ``None``: the
    mode's default, :data:`~jkatana.render.environment.SPLIT_MODES`) and ``env_window`` (the MIS modes'
    environment samples drawn in the lobe's window, :attr:`~jkatana.render.plan.Plan.env_window`; ``None``:
    the whole map)."""

    mode: str = "reference"
    samples: int = 64
    rank: int = 3
    seed: int = 0
    precision: str = "float32"
    chunk: int = 16384
    split_sun: bool | None = None
    env_window: float | None = None

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class FilmSpec:
    """XYZ → display: the RGB colourspace, its transfer (name, ``"linear"`` or a gamma), the exposure."""

    colourspace: str = "sRGB"
    transfer: str | float | None = None
    exposure: str | float = "auto"

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class OutputSpec:
    """Where frames go: ``directory/name.{exr,png}`` and, with ``spectral``, ``name_spectral.exr``."""

    directory: Path
    name: str = "frame"
    spectral: bool = False

    def to_dict(self) -> dict:
        return _table(self)


@dataclasses.dataclass(frozen=True)
class Scene:
    """A validated scene: one typed section per TOML table (paths resolved, nothing loaded yet)."""

    path: Path | None
    geometry: GeometrySpec
    material: MaterialSpec
    environment: EnvironmentSpec
    lights: tuple[LightSpec, ...]
    camera: CameraSpec
    spectral: SpectralSpec
    render: RenderSpec
    film: FilmSpec
    output: OutputSpec
    occluders: tuple[OccluderSpec, ...] = ()

    def with_output_directory(self, directory: str | Path) -> "Scene":
        """The same scene writing into ``directory``."""
        return dataclasses.replace(self, output=dataclasses.replace(self.output, directory=Path(directory)))

    def to_dict(self) -> dict:
        """The scene in the file schema (defaults filled in, paths absolute)."""
        d = {name: getattr(self, name).to_dict() for name in
             ("geometry", "material", "environment", "camera", "spectral", "render", "film", "output")}
        if self.lights:
            d["lights"] = [lt.to_dict() for lt in self.lights]
        if self.occluders:
            d["occluders"] = [oc.to_dict() for oc in self.occluders]
        return d


#: The reader's names reachable from this module (:func:`__getattr__`).
_READER_NAMES = ("load_scene", "scene_from_dict", "default_scene", "DEMO_SCENE")


def __getattr__(name: str):
    """``load_scene``, ``scene_from_dict``, ``default_scene`` and ``DEMO_SCENE`` of
    :mod:`jkatana.render.scenefile`, imported on first use (PEP 562), so that callers of this module
    keep them without an import cycle."""
    if name in _READER_NAMES:
        from jkatana.render import scenefile

        return getattr(scenefile, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""Memory a scene's environment needs, estimated from the map's size before a pixel of it is read.

A map read from a file is turned into spectra and prepared in several steps,
each holding full-size copies of the map at once: the RGB → spectrum
upsampling and its clean-up in float64 (:func:`jkatana.light.envmap.load_envmap`),
the sun detection and its remainder (:func:`jkatana.light.sun.split_compact_sources`),
the sampling tables (:class:`jkatana.light.sampling.EnvSampler`), the channels and
prefiltered levels (:func:`jkatana.render.environment.build_environment`), and
for ``view`` the float64 copy the viewer holds and the baked levels resampled to
the map's size (:func:`jkatana.interactive.bake.cached_bake`). The peak therefore
grows with texels × bands, many times the 4 bytes per value of the map itself;
a frame's own arrays (:func:`jkatana.render.commands.check_render_memory`) come on top.

:func:`environment_resolution` reads the size from the image header
(OpenImageIO opens the header only), so that :func:`environment_bytes` can be
checked against the budget (:func:`jkatana.io.limits.require_memory`) before
any work: a map that cannot fit is refused in one line naming its size and the
estimate, instead of the kernel's out-of-memory killer ending the process
minutes later.

A map read from a file whose whole spectra would not fit the budget is
instead *streamed* (:mod:`jkatana.render.streamed`): read in row blocks and
kept as a few hundred bytes a texel whatever its bands
(:data:`STREAM_BYTES_PER_TEXEL`). :func:`environment_route` chooses the path
(the whole spectra wherever they fit, so that such maps are prepared as
before) and :func:`environment_bytes` estimates the one chosen. ``view``
streams every map read from a file through its bake (:func:`jkatana.interactive.bake.cached_bake`
of a :class:`~jkatana.light.streaming.RowSource`, :data:`VIEW_STREAM_BYTES_PER_TEXEL`): the bake
needs only linear projections of the spectra, so the whole spectra are never
built for it. A map is refused only when even the streamed path cannot fit.

The per-value costs and the base are the slope and intercept of the peak RSS of a
first use on an empty cache against map size (the shared 1k HDR and its 2k resize,
``benchmarks/bench_first_use.py``), rounded up; ``tests/test_memory_estimate.py``
holds the estimate of the 1k map within a factor 1.5 of the measured peak.
"""

from __future__ import annotations

from pathlib import Path

#: Bytes per spectral value (texel × band) at the peak of a first ``render`` / ``light prefilter`` of a map
#: read from a file: the upsampled float32 map, its float64 clean-up copies, the sun split's remainder and
#: the sampler's float64 luminance work arrays alive together.
RENDER_BYTES_PER_VALUE = 48.0
#: Bytes per spectral value at the peak of a first ``view``: the render path's load (through the environment
#: cache), then the viewer's float64 copy and the bake's projection on the Fresnel basis.
VIEW_BYTES_PER_VALUE = 24.0
#: Bytes per texel of the baked levels ``view`` keeps at the map's size (11 μ levels × rank 3 × XYZ float32).
VIEW_BYTES_PER_TEXEL = 11 * 3 * 3 * 4
#: ``view``'s fit of a lobe family's taps on its first use (a region holding a parameter file: the paper's
#: lobes' tables ship with the package), whatever the map's size.
TAP_FIT_BYTES = 0.7 * 2 ** 30
#: The process before the environment: Python, NumPy, JAX and XLA's compiled programs, the mesh, the map.
BASE_BYTES = 0.6 * 2 ** 30
#: Bytes per texel at the peak of the streamed preparation (:mod:`jkatana.render.streamed`), whatever the
#: bands: the float32 RGB, the basis coefficients (up to 12 channels) and their device copy, the luminances,
#: and the sampler's float64 work arrays and float32 tables (a 6000×3000 map peaked at 3.7 GB, base included).
STREAM_BYTES_PER_TEXEL = 200.0
#: Bytes per texel at the peak of ``view``'s streamed bake (:func:`jkatana.interactive.bake.cached_bake` of a
#: :class:`~jkatana.light.streaming.RowSource`): the float32 RGB, the 9-channel projection on the Fresnel basis,
#: the luminance and the sun detection's work arrays.
VIEW_STREAM_BYTES_PER_TEXEL = 160.0
#: Bytes of the row blocks a streamed pass holds at once (about a million texels of spectra and projections).
STREAM_BLOCK_BYTES = 0.5 * 2 ** 30


def image_resolution(path: str | Path) -> tuple[int, int] | None:
    """``(height, width)`` of an EXR or Radiance HDR from its header alone (no pixel decoded), or None when the
    header cannot be read (the reader then reports the file's fault in its own words)."""
    try:
        import OpenImageIO as oiio
    except ImportError:  # pragma: no cover - OpenImageIO is a dependency
        return None
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear the error: the reader names it
        return None
    try:
        spec = inp.spec()
        return int(spec.height), int(spec.width)
    finally:
        inp.close()


def environment_resolution(environment) -> tuple[int, int] | None:
    """``(height, width)`` of a scene's :class:`~jkatana.render.scene.EnvironmentSpec`: its ``resolution`` for the
    built-in sky and constant environments, the file's header for ``exr`` and ``hdr``."""
    if environment.resolution is not None:
        return tuple(int(v) for v in environment.resolution)
    if environment.type in ("exr", "hdr") and environment.path is not None:
        return image_resolution(environment.path)
    return None


def full_bytes(environment, bands: int, *, interactive: bool = False) -> float:
    """Estimated peak bytes of preparing ``environment`` on ``bands`` wavelengths from its whole spectra
    (``interactive``: for ``view``), not counting :data:`BASE_BYTES` nor the frame."""
    size = environment_resolution(environment)
    if size is None:
        return 0.0
    texels = size[0] * size[1]
    if interactive:
        return texels * (bands * VIEW_BYTES_PER_VALUE + VIEW_BYTES_PER_TEXEL)
    return texels * bands * RENDER_BYTES_PER_VALUE


def streamed_bytes(environment, *, interactive: bool = False) -> float | None:
    """Estimated peak bytes of the streamed preparation (:mod:`jkatana.render.streamed`; ``interactive``: the
    bake's for ``view``) of a map read from a file, not counting :data:`BASE_BYTES`; None for an environment
    that is not read from a file."""
    size = environment_resolution(environment)
    if size is None or environment.type not in ("exr", "hdr"):
        return None
    per_texel = VIEW_STREAM_BYTES_PER_TEXEL if interactive else STREAM_BYTES_PER_TEXEL
    return size[0] * size[1] * per_texel + STREAM_BLOCK_BYTES


def environment_route(environment, bands: int, *, interactive: bool = False, max_memory=None,
                      extra: float = 0.0) -> str:
    """``"full"`` where the whole spectra fit the memory budget (:func:`jkatana.io.limits.memory_budget`) with
    ``extra`` bytes beside them, or where the map cannot be streamed; ``"streamed"`` otherwise. ``view``
    (``interactive``) streams every map read from a file: its bake keeps only linear projections of the
    spectra (on the Fresnel basis, a luminance), which the row source gives without the whole spectra."""
    from jkatana.io.limits import memory_budget

    stream = streamed_bytes(environment, interactive=interactive)
    if stream is None:
        return "full"
    if interactive:
        return "streamed"
    full = BASE_BYTES + extra + full_bytes(environment, bands, interactive=interactive)
    return "full" if full <= memory_budget(max_memory) or full <= BASE_BYTES + extra + stream else "streamed"


def environment_bytes(environment, bands: int, *, interactive: bool = False, max_memory=None,
                      extra: float = 0.0) -> float:
    """Estimated peak bytes of preparing ``environment`` on ``bands`` wavelengths the way it will be prepared
    (:func:`environment_route`), not counting :data:`BASE_BYTES` nor the frame."""
    if environment_route(environment, bands, interactive=interactive, max_memory=max_memory,
                         extra=extra) == "streamed":
        return streamed_bytes(environment, interactive=interactive)
    return full_bytes(environment, bands, interactive=interactive)


def describe(environment, bands: int) -> str:
    """``"a 6000×3000 (width × height) environment map big.exr, 61 bands"``, for the refusal."""
    size = environment_resolution(environment)
    shape = "an" if size is None else f"a {size[1]}×{size[0]} (width × height)"
    name = f" map {Path(environment.path).name}" if getattr(environment, "path", None) else ""
    return f"{shape} environment{name}, {bands} bands"


def environment_estimate(scene, *, interactive: bool = False, extra: float = 0.0, max_memory=None) -> float:
    """Estimated peak bytes of preparing ``scene``'s environment, plus ``extra`` bytes of frame, the process
    itself (:data:`BASE_BYTES`) and, for ``view`` of a scene whose regions name parameter files, a lobe
    family's tap fit (:data:`TAP_FIT_BYTES`)."""
    fit = interactive and (scene.material.hiraji is not None or scene.material.hamon is not None)
    extra = extra + (TAP_FIT_BYTES if fit else 0.0)
    return BASE_BYTES + environment_bytes(scene.environment, scene.spectral.grid.size, interactive=interactive,
                                          max_memory=max_memory, extra=extra) + extra


def check_environment_memory(scene, *, interactive: bool = False, max_memory=None, extra: float = 0.0) -> float:
    """Refuse, in one line naming the map's size and the estimate (:func:`environment_estimate`), a scene whose
    environment cannot fit the memory budget; returns the estimate in bytes."""
    from jkatana.io.limits import require_memory

    total = environment_estimate(scene, interactive=interactive, extra=extra, max_memory=max_memory)
    what = describe(scene.environment, scene.spectral.grid.size) + (" in view" if interactive else "")
    require_memory(total, environment_field(scene.environment), f"{what} (the whole request)", max_memory)
    return total


def environment_field(environment) -> str:
    """The scene field a refusal names: the file for a map read from one, else the resolution."""
    return "environment.path" if environment.type in ("exr", "hdr") else "environment.resolution"


__all__ = ["image_resolution", "environment_resolution", "environment_bytes", "environment_estimate",
           "full_bytes", "streamed_bytes", "environment_route", "STREAM_BYTES_PER_TEXEL", "VIEW_STREAM_BYTES_PER_TEXEL",
           "check_environment_memory", "environment_field", "RENDER_BYTES_PER_VALUE", "VIEW_BYTES_PER_VALUE",
           "TAP_FIT_BYTES", "BASE_BYTES"]

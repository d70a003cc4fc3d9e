"""Environment maps read in row blocks, for maps whose spectra do not fit in memory whole.

A 6000 × 3000 map on 61 wavelengths is 1.1 × 10⁹ spectral values: 4.4 GB as
float32 and twice that in the float64 steps of :func:`jkatana.light.envmap.load_envmap`.
A :class:`RowSource` never holds it whole. It hands out, per block of rows,
*linear projections* of the spectra (onto a spectral basis, a luminance): what
the streamed environment (:func:`jkatana.render.environment.build_streamed_environment`)
keeps per texel; and the exact spectra of chosen texels (a subsample for the
basis and its error, the texels of a sun).

- :class:`RGBRows`: an RGB HDR or EXR (read whole as float32 RGB, 12 bytes a
  texel), each texel's projected spectrum interpolated in a
  :func:`jkatana.light.upsampling.chromaticity_table` of the projection (every
  upsampling method is homogeneous of degree one), exact spectra by
  :func:`jkatana.light.upsampling.rgb_to_spectrum` itself.
- :class:`SpectralEXRRows`: a Fichet 2021 spectral EXR read in row blocks
  (:class:`jkatana.light.spectral_exr.SpectralRows`), projected exactly.

Both apply the clean-up of :func:`~jkatana.light.envmap.load_envmap`: the
radiance is ``max(L, 0) · scale``, non-finite pixels refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.spectral.grid import WavelengthGrid

#: Texels per block of a pass over a map: ~16 MB of float32 RGB and tens of MB of projections.
BLOCK_TEXELS = 1 << 20


class RowSource:
    """A map's spectra in row blocks (module docstring). ``path`` (the file), ``height``, ``width`` and ``grid``
    describe it."""

    height: int
    width: int
    grid: WavelengthGrid
    scale: float = 1.0

    def project(self, r0: int, r1: int, P: np.ndarray) -> np.ndarray:
        """Rows ``[r0, r1)`` of ``L @ P`` for a ``(wl, C)`` matrix ``P``: ``(r1 − r0, W, C)`` float32."""
        raise NotImplementedError

    def texels(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Exact spectra of the texels ``(rows[i], cols[i])``: ``(N, wl)`` float64."""
        raise NotImplementedError

    def bright(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows and columns of up to ``count`` of the map's brightest texels where the source can tell them
        without a pass over its spectra (for the spectral basis to represent a sun), else none."""
        return np.zeros(0, np.int64), np.zeros(0, np.int64)

    def project_all(self, P: np.ndarray, splits: tuple[int, ...]) -> list[np.ndarray]:
        """The whole map's ``L @ P`` in one pass of row blocks, its columns cut into arrays of ``splits``
        columns each (their sum is ``P``'s column count): ``(H, W, n)`` float32, or ``(H, W)`` where ``n`` is 0.
        Only those arrays are held whole, never a block's spectra or the whole projection."""
        P = np.asarray(P)
        if sum(max(n, 1) for n in splits) != P.shape[1]:
            raise ValueError(f"splits {splits} do not cover the projection's {P.shape[1]} columns")
        outs = [np.empty((self.height, self.width) + ((n,) if n else ()), np.float32) for n in splits]
        step = self.block_rows()
        for r0 in range(0, self.height, step):
            r1 = min(self.height, r0 + step)
            block, c0 = self.project(r0, r1, P), 0
            for out, n in zip(outs, splits):
                out[r0:r1] = block[..., c0:c0 + n] if n else block[..., c0]
                c0 += max(n, 1)
        return outs

    def block_rows(self, multiple: int = 1) -> int:
        """Rows per block: about :data:`BLOCK_TEXELS` texels, a multiple of ``multiple``."""
        rows = max(1, BLOCK_TEXELS // max(self.width, 1))
        return max(multiple, rows // multiple * multiple)


class RGBRows(RowSource):
    """An RGB map (:func:`~jkatana.light.envmap.read_rgb_image`) upsampled by ``method`` as projections."""

    def __init__(self, path, grid: WavelengthGrid, method: str = "Jakob 2019", scale: float = 1.0,
                 colourspace: str = "sRGB"):
        from jkatana.light.envmap import read_rgb_image

        self.path = Path(path)
        self.rgb = read_rgb_image(path)
        self.height, self.width = self.rgb.shape[:2]
        self.grid, self.method, self.scale, self.colourspace = grid, method, float(scale), colourspace
        self._tables: dict = {}

    def _table(self, P: np.ndarray) -> np.ndarray:
        from jkatana.light.upsampling import chromaticity_table

        key = P.tobytes()
        if key not in self._tables:
            self._tables = {key: chromaticity_table(lambda S: np.maximum(S, 0.0) @ P, self.method, self.grid,
                                                    colourspace=self.colourspace)}
        return self._tables[key]

    def project(self, r0, r1, P):
        from jkatana.light.upsampling import table_lookup

        P = np.asarray(P, np.float64)
        block = self.rgb[r0:r1].reshape(-1, 3)
        out = table_lookup(self._table(P), block) * np.float32(self.scale)
        return out.reshape(r1 - r0, self.width, P.shape[1])

    def bright(self, count):
        peak = self.rgb.max(axis=-1).ravel()
        count = min(int(count), peak.size)
        top = np.argpartition(peak, peak.size - count)[peak.size - count:] if count else np.zeros(0, np.int64)
        return np.divmod(top, self.width)

    def texels(self, rows, cols):
        from jkatana.light.upsampling import rgb_to_spectrum

        S = rgb_to_spectrum(self.rgb[rows, cols], self.method, self.grid, colourspace=self.colourspace)
        return np.maximum(np.asarray(S, np.float64), 0.0) * self.scale


class SpectralEXRRows(RowSource):
    """A spectral EXR read in row blocks (:class:`jkatana.light.spectral_exr.SpectralRows`)."""

    def __init__(self, path, grid: WavelengthGrid, scale: float = 1.0):
        from jkatana.light.spectral_exr import SpectralRows

        self.reader = SpectralRows(path, grid)
        self.path = self.reader.path
        self.height, self.width, self.grid, self.scale = self.reader.height, self.reader.width, grid, float(scale)

    def _rows(self, r0, r1) -> np.ndarray:
        from jkatana.light.envmap import check_radiance

        return np.maximum(check_radiance(self.reader.rows(r0, r1), self.reader.path), 0.0)

    def project(self, r0, r1, P):
        L = self._rows(r0, r1)
        return (L.reshape(-1, L.shape[-1]) @ np.asarray(P, np.float32) * np.float32(self.scale)).reshape(
            r1 - r0, self.width, -1)

    def texels(self, rows, cols):
        """Reads only the rows named, in runs of consecutive rows of at most :meth:`block_rows`."""
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        out = np.empty((rows.size, self.grid.size))
        wanted = np.unique(rows)
        step = self.block_rows()
        start = 0
        for k in range(1, wanted.size + 1):
            if k == wanted.size or wanted[k] != wanted[k - 1] + 1 or wanted[k] - wanted[start] >= step:
                lo, hi = int(wanted[start]), int(wanted[k - 1]) + 1
                sel = (rows >= lo) & (rows < hi)
                out[sel] = self._rows(lo, hi)[rows[sel] - lo, cols[sel]]
                start = k
        return out * self.scale


def row_source(path: str | Path, grid: WavelengthGrid, upsampling: str = "Jakob 2019", scale: float = 1.0,
               colourspace: str = "sRGB") -> RowSource:
    """The :class:`RowSource` of an environment file: spectral EXR or RGB (as
    :func:`~jkatana.light.envmap.load_envmap` reads it)."""
    from jkatana.errors import InputError
    from jkatana.light import spectral_exr

    path = Path(path)
    if not path.is_file():
        raise InputError("environment map not found", path=path)
    if path.suffix.lower() == ".exr" and spectral_exr.is_spectral_exr(path):
        return SpectralEXRRows(path, grid, scale)
    return RGBRows(path, grid, upsampling, scale, colourspace)


__all__ = ["RowSource", "RGBRows", "SpectralEXRRows", "row_source", "BLOCK_TEXELS"]

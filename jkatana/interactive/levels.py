"""The bake's prefiltered environment levels: one per μ, at a resolution fitted to μ, resampled for the shader.

The environment, projected on the Fresnel basis, is convolved with the
paper's Gaussian lobe at normal incidence for each μ of :data:`MU_LEVELS`
(:func:`jkatana.light.prefilter.prefilter_level`, the one prefilter of the
library: kernel f_r cos θi of the lobe at V = N, zero below the horizon;
Karis 2013, Walter et al. 2007), each level on the source box-downsampled to
≥ :data:`TEXELS_PER_MU` texels per μ (:func:`jkatana.light.prefilter.level_shape`),
then resampled bilinearly to the source's size (:func:`upsample`): the
shaders read one layer per μ from one 3-D texture.
"""

from __future__ import annotations

import numpy as np

from jkatana.light.prefilter import level_shape  # noqa: F401 (the levels' resolution, for readers)
from jkatana.light.prefilter import prefilter_level as _light_prefilter_level

#: μ levels of the prefiltered environment (radians, log-spaced, ratio √2; 0.05 is a level).
MU_LEVELS = 0.0125 * np.sqrt(2.0) ** np.arange(11)

#: Level resolution of the bake: texel height ≤ μ / this (the Gaussian kernel's FWHM, 4μ, spans ≥ 8 texels).
TEXELS_PER_MU = 2.0


def prefilter_level(image: np.ndarray, mu: float, *, texels_per_mu: float = TEXELS_PER_MU,
                    chunk: int = 32) -> np.ndarray:
    """An equirectangular image ``(H, W, C)`` convolved with the paper's Gaussian lobe of width ``mu``
    (:func:`jkatana.light.prefilter.prefilter_level`, kernel sampled at texel centres), at
    :func:`level_shape`'s resolution for ``texels_per_mu``."""
    return _light_prefilter_level(image, mu, texels_per_mu=texels_per_mu, sub=1, chunk=chunk)


def upsample(level: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear resampling of an equirectangular ``(h, w, C)`` level to ``(height, width, C)``
    (texel centres; longitude wraps, latitude clamps at the poles)."""
    h, w = level.shape[:2]
    if (h, w) == (height, width):
        return np.asarray(level)
    y = np.clip((np.arange(height) + 0.5) * h / height - 0.5, 0.0, h - 1.0)
    j0 = np.minimum(np.floor(y).astype(int), max(h - 2, 0))
    fy = (y - j0)[:, None, None].astype(level.dtype)
    rows = level[j0] * (1 - fy) + level[np.minimum(j0 + 1, h - 1)] * fy                # (height, w, C)
    x = (np.arange(width) + 0.5) * w / width - 0.5
    i0 = np.floor(x).astype(int)
    fx = (x - i0)[None, :, None].astype(level.dtype)
    return rows[:, i0 % w] * (1 - fx) + rows[:, (i0 + 1) % w] * fx


def prefilter(image: np.ndarray, mu: float) -> np.ndarray:
    """:func:`prefilter_level` resampled to the image's resolution (:func:`upsample`)."""
    H, W = image.shape[:2]
    return upsample(prefilter_level(image, mu), H, W)

"""How far one image's colours are from a reference's, as a display shows both: the comparison every
benchmark, validation and experiment reports.

:func:`delta_e_display` sets the exposure from the reference alone (its 99th-percentile luminance Y maps to
display white, :func:`reference_exposure`), takes the display-referred CIEDE2000 of each colour pair
(:func:`jkatana.spectral.delta_e_2000`: both sides through the same :func:`~jkatana.spectral.to_display`;
Sharma, Wu & Dalal 2005 for ΔE2000) and summarises it (:func:`delta_e_stats`: mean, percentiles, max).
"""

from __future__ import annotations

import numpy as np

from jkatana.spectral.colorimetry import delta_e_2000


def reference_exposure(xyz_ref, percentile: float = 99.0) -> float:
    """``1 / Y_p`` of the reference colours ``xyz_ref (..., 3)`` (``Y_p`` their ``percentile``-th percentile
    luminance), so that ``Y_p`` maps to display white; 1 where ``Y_p`` is not positive."""
    y = float(np.percentile(np.asarray(xyz_ref, np.float64).reshape(-1, 3)[:, 1], percentile))
    return 1.0 / y if y > 0 else 1.0


def delta_e_stats(de, *, percentiles=(95.0,), prefix: str = "dE2000_") -> dict[str, float]:
    """``{prefix + "mean", prefix + "p95", …, prefix + "max"}`` of the ΔE values ``de`` (one key per
    entry of ``percentiles``, named ``p`` and the percentile as ``%g`` formats it). Non-finite values are not
    dropped: the headline numbers are then non-finite, and ``nonfinite_frac`` with the ``*_finite`` keys (mean
    and percentiles) say how the rest fared."""
    de = np.asarray(de, np.float64).ravel()
    out = {prefix + "mean": float(np.mean(de))}
    out.update({f"{prefix}p{q:g}": float(np.percentile(de, q)) for q in percentiles})
    out[prefix + "max"] = float(np.max(de))
    finite = np.isfinite(de)
    if not finite.all():
        out["nonfinite_frac"] = float(1.0 - finite.mean())
        if finite.any():
            out[prefix + "mean_finite"] = float(np.mean(de[finite]))
            out.update({f"{prefix}p{q:g}_finite": float(np.percentile(de[finite], q)) for q in percentiles})
    return out


def delta_e_display(xyz_ref, xyz, *, exposure: float | None = None, colourspace: str = "sRGB",
                    percentiles=(95.0,), return_de: bool = False):
    """Display-referred CIEDE2000 between colours ``xyz (..., 3)`` and the reference's ``xyz_ref`` (CIE XYZ),
    summarised (:func:`delta_e_stats`).

    ``exposure`` defaults to :func:`reference_exposure` of ``xyz_ref`` (its 99th-percentile Y to display
    white); both sides are shown with it in ``colourspace``.

    **Returns:** ``{"dE2000_mean", "dE2000_p95" (one key per percentile), "dE2000_max", "exposure",
    "pixels"}`` (and the ``*_finite`` keys where a ΔE is not finite); with ``return_de`` also the ΔE per
    colour pair, ``(stats, de (...))``.
    """
    xyz_ref = np.asarray(xyz_ref, np.float64)
    xyz = np.asarray(xyz, np.float64)
    if exposure is None:
        exposure = reference_exposure(xyz_ref)
    de = delta_e_2000(xyz_ref, xyz, exposure=exposure, colourspace_name=colourspace)
    out = delta_e_stats(de, percentiles=percentiles)
    out["exposure"] = float(exposure)
    out["pixels"] = int(np.size(de))
    return (out, de) if return_de else out


__all__ = ["delta_e_display", "delta_e_stats", "reference_exposure"]

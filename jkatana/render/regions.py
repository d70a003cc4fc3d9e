"""The lobes a frame's pixels render with, per region of the blade (hiraji, hamon).

Each region's lobe is the paper's (hiraji :class:`~jkatana.models.lobes.Gaussian`,
Mochizuki et al. eq. 1; hamon :class:`~jkatana.models.lobes.GaussianVCavity`, eq. 2)
or any lobe a parameter file names (``Plan.hiraji_lobe``/``hamon_lobe``), at the
per-pixel width of the reflectance map, blended by w and 1 − w (eq. 5) and sampled
as one :class:`~jkatana.models.lobes.Mixture`. Used by every mode of
:func:`jkatana.render.shading.shade` and by the cap rules of :mod:`jkatana.render.caps`.
"""

from __future__ import annotations

import jax.numpy as jnp

from jkatana.models.lobes import Gaussian, GaussianVCavity, Mixture
from jkatana.models.microfacet import gaussian_normalisation
from jkatana.render.fresnel_fold import Material
from jkatana.render.plan import LOBE_MODES, Pixels, Plan


def _norms(plan: Plan, mat: Material, px: Pixels):
    """Per-pixel lobe scales: N(μ) of the paper's lobes (normalised convention; ``None`` where a region has
    another lobe, normalised by itself) or χ/K, β/K (calibrated). Hoisted out of the sample loop."""
    if plan.calibration is None:
        n0 = (gaussian_normalisation(px.mu0) if (plan.hiraji and not plan.mirror and plan.hiraji_lobe is None)
              else None)
        n1 = gaussian_normalisation(px.mu1) if (plan.hamon and plan.hamon_lobe is None) else None
        return n0, n1
    return mat.chi / plan.calibration, mat.beta / plan.calibration


def _region_lobe(plan: Plan, key, width, norm, paper):
    """``(lobe, gain)`` of one region: the paper's lobe ``paper`` (scale ``norm``, gain ``None``) or, for a
    :class:`~jkatana.models.lobe_id.LobeId` at unit width, that lobe at the per-pixel ``width``.

    Another lobe in the normalised convention is its energy-normalised form
    (:meth:`~jkatana.models.lobe_id.LobeId.normalised`, gain ``None``); calibrated,
    it is the lobe as fitted times ``norm`` = s/K, where s is the params file's
    scale: the fit's model is ρ = s · f_r cos θi · F̄ (:mod:`jkatana.fit._model`),
    so s/K converts camera units to reflectance exactly as χ/K does for the
    paper's lobe.
    """
    normalised = plan.calibration is None
    if key is None:
        return paper(width, norm, normalised=normalised), None
    if plan.mode not in LOBE_MODES:
        raise ValueError(f"lobe {key.family!r} renders in modes {list(LOBE_MODES)} only, not {plan.mode!r}")
    return key.rendered(plan.calibration).at_width(width, width.dtype), (None if normalised else norm)


def region_lobe_keys(lobes: dict, calibration: float | None) -> tuple:
    """``(hiraji, hamon)``: the :meth:`~jkatana.models.lobe_id.LobeId.rendered` identity of each region's lobe in
    ``lobes``, ``None`` for the paper's."""
    return tuple(None if lobes[r] is None else lobes[r].rendered(calibration) for r in ("hiraji", "hamon"))


def _lobes(plan: Plan, px: Pixels, norms):
    """The sampled lobes of the pixels with their blend weights and gains: ``[(lobe, weight, gain), ...]``.

    Hiraji: ``plan.hiraji_lobe`` at width μ0 (the paper's
    :class:`~jkatana.models.lobes.Gaussian` when ``None``) unless it is a perfect
    mirror, weight w; hamon: ``plan.hamon_lobe`` at width μ1 (the paper's
    :class:`~jkatana.models.lobes.GaussianVCavity` when ``None``), weight 1 − w
    (Mochizuki et al., eq. 5). ``gain`` (``None``: 1) multiplies a lobe's value
    but not its sampling weight.
    """
    out = []
    if plan.hiraji and not plan.mirror:
        lobe, gain = _region_lobe(plan, plan.hiraji_lobe, px.mu0, norms[0], Gaussian)
        out.append((lobe, px.w, gain))
    if plan.hamon:
        lobe, gain = _region_lobe(plan, plan.hamon_lobe, px.mu1, norms[1], GaussianVCavity)
        out.append((lobe, 1.0 - px.w, gain))
    return out


def _sampler(lobes):
    """One lobe, or the blend of two sampled by its weights (:class:`~jkatana.models.lobes.Mixture`)."""
    if len(lobes) == 1:
        return lobes[0][0]
    (a, w, _), (b, _, _) = lobes
    return Mixture(a, b, w)


def _mix_w(plan: Plan, px: Pixels):
    """Probability of sampling the hiraji lobe."""
    if plan.mirror or not plan.hiraji:
        return jnp.zeros_like(px.w)
    if not plan.hamon:
        return jnp.ones_like(px.w)
    return px.w


def _fcos_terms(lobes, L, V):
    """f·cos θi without Fresnel per lobe term, weighted by the blend and gain: ``[(a, Fresnel cosine), ...]``."""
    return [((w * a) if g is None else (w * g) * a, c) for lobe, w, g in lobes for a, c in lobe.terms(L, V)]



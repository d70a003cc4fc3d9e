"""The shader's static plan and the per-pixel inputs it reads.

A :class:`Plan` holds every trace-time choice of :func:`jkatana.render.shading.shade`
(mode, sample count, which lobes and effects are present); it is hashable and part
of the compile key, so changing any field compiles a new program. :class:`Pixels`,
:class:`Light`, :class:`Rays` and :class:`Visibility` are the arrays that pass between
the G-buffer, the host-side ray caster and the jitted shader.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

from jaxtyping import Array, Float

from jkatana.models.lobe_id import LobeId
from jkatana.render.integrators import INTEGRATORS

#: Below this μ0 (radians) the hiraji lobe is treated as a perfect mirror (one lookup).
MIRROR_MU = 1e-4
#: The render modes: the integrators' names (:data:`~jkatana.render.integrators.INTEGRATORS`).
MODES = tuple(INTEGRATORS)
#: The modes that render a lobe other than the paper's (:attr:`Integrator.any_lobe
#: <jkatana.render.integrators.Integrator.any_lobe>`): the sampling modes (through the lobe's own
#: ``sample``/``pdf``) and the prefiltered mode (levels convolved with the region's own lobe), in that order.
LOBE_MODES = tuple(sorted((name for name, i in INTEGRATORS.items() if i.any_lobe),
                          key=lambda name: not INTEGRATORS[name].sampled))
#: The Monte Carlo modes (:attr:`Integrator.sampled <jkatana.render.integrators.Integrator.sampled>`: lobe and
#: environment samples combined by MIS): their default Fresnel rank is
#: chosen to :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL_SAMPLED`, the other modes' to
#: :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL`.
SAMPLED_MODES = frozenset(name for name, i in INTEGRATORS.items() if i.sampled)

#: A good ``Plan.env_window`` k (the window's half-angle is 2 atan(k μ)): the lowest-noise k at low sample counts
#: on the Mitsuba comparison's rough sphere (its benchmark report has the study).
ENV_WINDOW = 2.0


@dataclasses.dataclass(frozen=True)
class Plan:
    """Static (trace-time) choices of what the shader computes.

    **Fields:**

    - `mode`: one of :data:`MODES` (``"paper-published"``: the paper's rays on the whole map, no cap).
    - `samples`: lobe samples per pixel (``"reference"``/``"lowrank"``: beside
      `env_samples` environment samples, by default as many; ``"paper"``: jittered rays).
    - `hiraji`, `hamon`: whether any pixel has w > 0 / w < 1.
    - `mirror`: hiraji treated as a perfect mirror (μ0 < MIRROR_MU everywhere).
    - `env_sampling`: importance-sample the environment too (MIS).
    - `env_samples`: environment samples per G-buffer sample in the MIS modes
      (``None``: ``samples``, one environment sample beside each lobe sample).
      The two strategies are combined by the balance heuristic with sample
      counts (Veach & Guibas 1995, §3: ``w_i = n_i p_i / Σ_k n_k p_k``), so any
      count ≥ 0 keeps the estimator unbiased; the best ratio depends on how
      much of the integrand each strategy finds (a lobe much narrower than
      the map's bright regions: fewer; a map whose power sits in small bright
      regions: more).
    - `env_window`: the MIS modes draw their environment samples inside a texel
      window about each pixel's mirror direction, a cone of half-angle
      ``2 atan(k μ)`` with ``k = env_window`` and μ the pixel's lobe width
      (:func:`~jkatana.render.integrators.mis.env_window`); ``None`` or 0 (default): from
      the whole map. Unbiased for any ``k`` (the lobe strategy covers what the
      window leaves out), and a large gain where the map's power is spread and
      much of it lies below the horizon or far from the lobe (:data:`ENV_WINDOW`).
      Not the default because a bright source *outside* the window but in the
      lobe's tail (a sun a few lobe widths from the mirror direction) is then
      found by the lobe samples alone, which raises some pixels' variance on a
      sky with its sun in the map. Split the sun
      into caps (``build_environment(split_sun=...)``), which MIS samples on
      their own, before turning the window on for such maps.
    - `factored`: shade in the environment's spectral basis (rank = its channels).
    - `fresnel_rank`: ``R > 0``: shade with the Fresnel factor folded into the
      environment (:func:`~jkatana.render.fresnel_fold.fold_fresnel`: per sample a ``3R``-channel lookup and
      ``R`` Fresnel coefficients instead of ``wl`` bands; the caller passes the
      folded material and environment). ``0``: full spectra. ``None`` (default):
      :func:`jkatana.render.dispatch.shade_pixels` picks the smallest ``R`` whose
      Fresnel table residual is below :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL_SAMPLED` in the
      modes of :data:`SAMPLED_MODES` and :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL` in the others,
      when the plan allows it (no spectral output, no lights, not ``factored``), else 0;
      :func:`~jkatana.render.shading.shade` called directly treats ``None`` as 0.
    - `lights`: number of point/directional lights (0: none evaluated).
    - `calibration`: ``None`` for the normalised convention, else K (see models).
    - `hiraji_lobe`, `hamon_lobe`: the region's lobe other than the paper's, as
      :class:`jkatana.models.lobe_id.LobeId` (family and static parameters,
      every width relative to the primary one; the per-pixel μ0 / μ1 of the maps
      is that primary width), or ``None`` for the paper's lobe (hiraji: eq. 1,
      :class:`~jkatana.models.lobes.Gaussian`; hamon: eq. 2,
      :class:`~jkatana.models.lobes.GaussianVCavity`). A key of
      :class:`~jkatana.models.lobes.Beckmann` in the hamon slot is Mitsuba 3's
      ``roughconductor`` (Beckmann D, α = μ1, Walter et al.'s 2007 rational
      Smith G1), for validation against it. Rendered by the modes of
      :data:`LOBE_MODES` (the sampling modes, and the prefiltered mode from the
      region's own levels, :attr:`~jkatana.render.environment.Environment.lobe_prefiltered`).
    - `spectral`: also return spectra (full mode only).
    - `visibility`: the scene has occluders: every traced light direction is
      weighted by a host-computed visibility (:class:`Visibility`). ``False``
      (no occluders) compiles no visibility input at all.
    - `subpixels`: ``S`` G-buffer samples (subpixels) per output pixel. With
      ``S > 1`` and :class:`~jkatana.render.points.PixelIds` passed to :func:`~jkatana.render.shading.shade`, the MIS modes draw
      ONE per-pixel point set of ``S × samples`` points and give each subpixel
      its share (subpixel ``q`` takes points ``q·N … q·N + N − 1`` of the pixel's
      ``S·N``-point Sobol sequence under the pixel's digital shift), so that the union over a pixel's
      subpixels is one well-stratified set instead of ``S`` independently
      shifted ones. Without ids (or ``S = 1``) every G-buffer sample is its own pixel.
    - `cap_rule`: how the prefiltered and paper modes integrate the environment's
      split caps (:attr:`~jkatana.render.environment.Environment.caps`):
      ``"nodes"`` (:func:`jkatana.light.capquad.cap_nodes`, 64 lobe evaluations per
      pixel and cap, any lobe width) or ``"stroud"``
      (:func:`jkatana.light.capquad.cap_disc_nodes`, 4, for lobes ≥ 8 cap radii
      wide), or one of those per lobe part, comma-separated (``"nodes,stroud"``).
      ``None``: :func:`jkatana.render.dispatch.shade_pixels` picks it per lobe from the
      pixels' lobe widths (:func:`~jkatana.render.caps.cap_rule_for`);
      :func:`shade` called directly treats ``None`` as ``"nodes"``.
    """

    mode: str = "reference"
    samples: int = 64
    hiraji: bool = True
    hamon: bool = True
    mirror: bool = False
    env_sampling: bool = True
    env_samples: int | None = None
    env_window: float | None = None
    factored: bool = False
    fresnel_rank: int | None = None
    lights: int = 0
    hiraji_lobe: LobeId | None = None
    hamon_lobe: LobeId | None = None
    calibration: float | None = None
    spectral: bool = False
    visibility: bool = False
    subpixels: int = 1
    cap_rule: str | None = None  # "nodes" | "stroud" | one per lobe part ("nodes,stroud"); None: chosen per frame

    @property
    def n_env(self) -> int:
        """Environment samples per G-buffer sample of the MIS modes (0 without environment sampling)."""
        if not self.env_sampling:
            return 0
        return self.samples if self.env_samples is None else int(self.env_samples)


class Light(NamedTuple):
    """Point (``kind`` 0: position, intensity W sr⁻¹ nm⁻¹) or directional (1: direction to light, irradiance)."""

    vector: Float[Array, "n 3"]
    kind: Float[Array, "n"]
    spectrum: Float[Array, "n wl"]


class Pixels(NamedTuple):
    """G-buffer pixels (flattened, padded): world position, normal, view direction, per-pixel material."""

    position: Float[Array, "P 3"]
    normal: Float[Array, "P 3"]
    view: Float[Array, "P 3"]
    w: Float[Array, "P"]
    mu0: Float[Array, "P"]
    mu1: Float[Array, "P"]


class Rays(NamedTuple):
    """World directions the shader will trace for given pixels and key
    (:func:`~jkatana.render.shading.ray_directions`).

    Pixel axis first everywhere (so one sharding splits them): ``mirror (P, 3)``
    (mirror direction: the mirror hiraji and the prefiltered lookups),
    ``lobe (P, S, 3)`` (lobe-sampled or the paper's jittered rays), ``env (P, S, 3)``
    (environment samples of MIS; empty ``S = 0`` otherwise), ``lights (P, n, 3)`` and
    ``light_dist (P, n)`` (distance to a point light, ``inf`` for directional ones).
    """

    mirror: Float[Array, "P 3"]
    lobe: Float[Array, "P S 3"]
    env: Float[Array, "P S2 3"]
    lights: Float[Array, "P n 3"]
    light_dist: Float[Array, "P n"]


class Visibility(NamedTuple):
    """1 where the direction of the matching :class:`Rays` entry reaches the environment/light, else 0."""

    mirror: Float[Array, "P"]
    lobe: Float[Array, "P S"]
    env: Float[Array, "P S2"]
    lights: Float[Array, "P n"]

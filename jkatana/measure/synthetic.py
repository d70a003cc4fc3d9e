"""Synthetic goniometer, in memory: the measurement table a campaign would give.

:func:`simulate_table` evaluates the paper's models (eq. 1 hiraji, eq. 2
hamon; :mod:`jkatana.models`) at the protocol's geometry, integrates them
against a light spectrum and a camera green sensitivity
(:mod:`jkatana.measure.camera`: ρ = (C/E) @ w, so χ and β stay in camera
units), and optionally adds the effects a real rig has. The RAW-file
goniometer (:mod:`jkatana.measure.goniometer`) uses the same truth and writes
DNG files instead.

Effects — each is off unless asked for:

- **noise** (:class:`NoiseModel`): per-row standard deviation
  σ² = (relative·ρ)² + shot·ρ + absolute², i.e. a multiplicative term (source
  flicker), a shot-like term (Poisson: variance ∝ signal) and an absolute
  floor (read noise, quantisation). ``sigma`` in the table is this σ at the
  truth; 0 when noiseless.
- **tilt** ``tilt_deg`` = t: the sample is rotated by t in the plane of
  incidence, *positive towards the light*. The surface then sees
  θi' = θi − t and θr' = θr + t, so the specular peak moves to
  θr = θi − 2t. The table keeps the nominal (commanded) angles.
- **angle jitter** ``angle_jitter_deg``: the true θi, θr of each capture
  differ from the nominal ones by independent N(0, jitter²) errors (the arm
  is set by hand, SPEC §4). The table keeps the nominal angles.
- **stray-light floor** ``stray_floor``: a constant added to every value
  (camera units): flare, ambient light, the dark tail of the lobe.

The *truth* returned beside the table is the expected measurement — the
model at the true (tilted, jittered) geometry plus the stray floor, without
random noise — so ``(value − truth) / sigma`` is standard normal.
"""

from __future__ import annotations

import numpy as np

from jkatana.errors import InputError
from jkatana.measure.camera import DEFAULT_CAMERA, band_weights, camera_sensitivity, light_spectrum
from jkatana.measure.noise import NoiseModel
from jkatana.measure.protocol import as_pairs
from jkatana.measure.table import MeasurementTable, check_angles
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


def region_model(region: str, params=None):
    """The paper's model for ``region`` with ``params`` (None: paper's fit; a dict; or a Module)."""
    import jax
    import jax.numpy as jnp

    from jkatana.models import PAPER_HAMON, PAPER_HIRAJI, Hamon, Hiraji

    if region == "hiraji":
        cls, default = Hiraji, PAPER_HIRAJI
    elif region == "hamon":
        cls, default = Hamon, PAPER_HAMON
    else:
        raise InputError(f"can simulate regions 'hiraji' and 'hamon', not {region!r}", field="region")
    if params is None:
        params = default
    if isinstance(params, (Hiraji, Hamon)):
        if not isinstance(params, cls):
            raise InputError(f"params are a {type(params).__name__}, region {region!r} needs "
                             f"{cls.__name__}", field="params")
        return params
    from jkatana.models.bounds import region_params

    merged = {**default, **region_params(region, dict(params))}  # widths > 0, scales finite and > 0
    with jax.enable_x64(True):
        return cls(**{k: jnp.asarray(float(v), jnp.float64) for k, v in merged.items()})


def green_values(theta_i_deg, theta_r_deg, region: str = "hiraji", params=None, *,
                 optical_constants: str = "Fe-Johnson", light="D65", camera=DEFAULT_CAMERA,
                 grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """Noiseless camera green values ρ of the region's model at the *true* angles (degrees).

    Angles may be signed (a tilted sample); the model returns 0 where the
    light or the receiver is below the surface.
    """
    import jax
    import jax.numpy as jnp

    from jkatana.models import Conductor

    w = band_weights(light_spectrum(light, grid), camera_sensitivity(camera, grid), grid)
    with jax.enable_x64(True):  # the simulator's truth is float64 whatever the global setting
        model = region_model(region, params)
        conductor = Conductor.from_table(optical_constants, grid, jnp.float64)
        ti = jnp.asarray(theta_i_deg, jnp.float64)
        tr = jnp.asarray(theta_r_deg, jnp.float64)
        return np.asarray(_green(model, ti, tr, conductor, jnp.asarray(w, jnp.float64)), np.float64)


def _green_impl(model, ti_deg, tr_deg, conductor, w):
    import jax.numpy as jnp

    from jkatana.models import in_plane

    L, V = in_plane(jnp.deg2rad(ti_deg), jnp.deg2rad(tr_deg))
    return model.camera(L, V, conductor) @ w  # C/E: the E=None form, camera units


def _green(*args):
    global _GREEN_JIT
    if _GREEN_JIT is None:
        import equinox as eqx

        _GREEN_JIT = eqx.filter_jit(_green_impl)
    return _GREEN_JIT(*args)


_GREEN_JIT = None


def true_angles(pairs, *, tilt_deg: float = 0.0, angle_jitter_deg: float = 0.0,
                rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Angles the surface really sees: tilt (θi − t, θr + t) and jitter (module docstring)."""
    pairs = np.asarray(pairs, np.float64).reshape(-1, 2)
    ti, tr = pairs[:, 0] - tilt_deg, pairs[:, 1] + tilt_deg
    if angle_jitter_deg:
        rng = np.random.default_rng(0) if rng is None else rng
        ti = ti + rng.normal(0.0, angle_jitter_deg, ti.shape)
        tr = tr + rng.normal(0.0, angle_jitter_deg, tr.shape)
    return ti, tr


def simulate_table(protocol=None, region: str = "hiraji", params=None, *,
                   optical_constants: str = "Fe-Johnson", light="D65", camera=DEFAULT_CAMERA,
                   noise: NoiseModel | None = None, tilt_deg: float = 0.0, stray_floor: float = 0.0,
                   angle_jitter_deg: float = 0.0, grid: WavelengthGrid = DEFAULT_GRID,
                   seed: int = 0) -> tuple[MeasurementTable, np.ndarray]:
    """Simulate a campaign's measurement table in memory (module docstring).

    **Arguments:**

    - `protocol`: a :class:`~jkatana.measure.protocol.Protocol`, a list of
      ``(θi, θr)`` pairs in degrees, or None for the paper's protocol.
    - `region`: ``"hiraji"`` (eq. 1) or ``"hamon"`` (eq. 2).
    - `params`: None (the paper's fit: χ = 79000, μ0 = 0.05 / β = 43000,
      μ1 = 0.05), a dict such as ``{"chi": 5e4, "mu": 0.03}``, or a model Module.
    - `optical_constants`: shipped name ("Fe-Johnson", "Fe-Querry") or a YAML path.
    - `light`: illuminant name/CCT or an array on ``grid``.
    - `camera`: colour-science camera name (green channel) or an array on ``grid``.
    - `noise`: a :class:`NoiseModel` (default: none).
    - `tilt_deg`, `stray_floor`, `angle_jitter_deg`: effects (module docstring).
    - `grid`: wavelength grid. `seed`: random seed (noise, jitter).

    **Returns:** ``(table, truth)``: the noisy :class:`MeasurementTable` (nominal
    angles, capture ids ``"i15.0_r10.2"``) and the noiseless expected values ``(rows,)``.
    """
    pairs = as_pairs(protocol)
    for row, (a, b) in enumerate(pairs, start=1):
        check_angles(a, b, path="protocol", row=row)
    if not np.isfinite(stray_floor) or stray_floor < 0:
        raise InputError(f"stray-light floor must be finite and >= 0, got {stray_floor}", field="stray_floor")
    noise = NoiseModel() if noise is None else noise
    rng = np.random.default_rng(seed)
    ti, tr = true_angles(pairs, tilt_deg=tilt_deg, angle_jitter_deg=angle_jitter_deg, rng=rng)
    truth = green_values(ti, tr, region, params, optical_constants=optical_constants, light=light,
                         camera=camera, grid=grid) + stray_floor
    sigma = noise.sigma(truth)
    value = truth + (rng.normal(0.0, 1.0, truth.shape) * sigma if not noise.is_zero else 0.0)
    nominal = np.asarray(pairs, np.float64).reshape(-1, 2)
    table = MeasurementTable.from_columns(
        capture=[capture_id(a, b) for a, b in pairs], region=[region] * len(pairs),
        theta_i_deg=nominal[:, 0], theta_r_deg=nominal[:, 1], value=value, sigma=sigma)
    return table, truth


def capture_id(theta_i_deg: float, theta_r_deg: float) -> str:
    """Capture id for a protocol pair, e.g. ``i15.0_r10.2``."""
    return f"i{theta_i_deg:.1f}_r{theta_r_deg:.1f}"


__all__ = ["NoiseModel", "simulate_table", "green_values", "region_model", "true_angles", "capture_id"]

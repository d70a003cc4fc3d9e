"""Camera green-channel sensitivity and the band weights that turn a spectrum into ρg.

The paper fits its models to the camera's green channel ρg (Mochizuki et al.,
§6.1), but the models are spectral. SPEC §4 asks that the model's green value
be the spectral model integrated against a green sensitivity and the source
spectrum, not read off a single wavelength. This module supplies both pieces.

**Sensitivity.** The default is a *measured* camera: the green channel of the
"Nikon 5100 (NPL)" spectral sensitivities shipped by colour-science
(``colour.MSDS_CAMERA_SENSITIVITIES``; measured at the UK National Physical
Laboratory, Darrodi, Finlayson, Goodman, Mackiewicz 2015, "Reference data set
for camera spectral sensitivity estimation", JOSA A 32(3) 381–391). colour-science
also ships "Sigma SDMerill (NPL)" (400–680 nm only, so it does not cover the
default 400–700 nm grid and is refused there rather than extrapolated). The
paper's Canon EOS 40D curve is not public; any ``(wl,)`` array on the grid can
be passed instead.

**Convention (camera units).** A camera sees the reflected radiance
C(λ) = f(λ) E(λ), where f is the model's spectral factor (e.g. χ D F for the
hiraji) and E the source. Its green value is Σλ C(λ) s(λ) Δλ up to a constant.
jkatana chooses the constant so that χ and β *stay in camera units*:

    w(λ) = E(λ) s(λ) Δλ / Σλ' E(λ') s(λ') Δλ'            (Σ w = 1)
    ρ = (C(λ) / E(λ)) @ w = Σλ f(λ) w(λ)

so a model whose spectral factor is a constant F gives exactly ρ = χ D F —
the paper's eq. (3) with F replaced by its E·s-weighted mean over the band.
The weights are a plain array, so fitting code can compute
``model.camera(L, V, conductor) @ w`` (the ``E=None`` form of the models)
inside ``jit``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from jaxtyping import Float

from jkatana.errors import InputError
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid, resample

#: The default camera: a measured sensitivity shipped by colour-science.
DEFAULT_CAMERA = "Nikon 5100 (NPL)"


@functools.lru_cache(maxsize=16)
def _sensitivity(grid: WavelengthGrid, camera: str, channel: str) -> np.ndarray:
    import colour

    try:
        msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    except KeyError:
        known = ", ".join(sorted(colour.MSDS_CAMERA_SENSITIVITIES))
        raise InputError(f"unknown camera {camera!r} (colour-science ships: {known})",
                         field="camera") from None
    labels = [str(label).lower() for label in msds.labels]
    if channel not in labels:
        raise InputError(f"camera {camera!r} has no {channel!r} channel ({labels})", field="channel")
    values = np.asarray(msds.values, np.float64)[:, labels.index(channel)]
    out = resample(np.asarray(msds.wavelengths, np.float64), values, grid, name=f"camera {camera!r}")
    out = np.clip(out, 0.0, None)
    out.setflags(write=False)
    return out


def green_sensitivity(grid: WavelengthGrid = DEFAULT_GRID, camera: str = DEFAULT_CAMERA,
                      channel: str = "green") -> Float[np.ndarray, "wl"]:
    """Relative spectral sensitivity of a real camera's green channel on ``grid``.

    **Arguments:**

    - `grid`: the wavelength grid.
    - `camera`: a key of colour-science's ``MSDS_CAMERA_SENSITIVITIES``
      (default ``"Nikon 5100 (NPL)"``, Darrodi et al. 2015).
    - `channel`: ``"green"`` (default), ``"red"`` or ``"blue"``.

    **Returns:** ``(len(grid),)`` float64, peak ≈ 1, read-only. A grid outside
    the measured range raises :class:`InputError` (no extrapolation).
    """
    return _sensitivity(grid, camera, channel.lower())


def band_weights(E, sensitivity, grid: WavelengthGrid = DEFAULT_GRID) -> Float[np.ndarray, "wl"]:
    """Normalised band weights w(λ) = E s Δλ / Σ E s Δλ (module docstring).

    **Arguments:**

    - `E`: source spectral power on ``grid``, ``(wl,)``.
    - `sensitivity`: camera channel sensitivity on ``grid``, ``(wl,)``.
    - `grid`: the wavelength grid (its step is Δλ).

    **Returns:** ``(wl,)`` non-negative weights summing to 1, such that the
    camera value of a reflected spectrum C is ``(C / E) @ w``.
    """
    E = np.asarray(E, np.float64)
    s = np.asarray(sensitivity, np.float64)
    if E.shape != (grid.size,) or s.shape != (grid.size,):
        raise InputError(f"light {E.shape} and sensitivity {s.shape} must both be ({grid.size},) "
                         "on the grid", field="light")
    if not (np.all(np.isfinite(E)) and np.all(np.isfinite(s))):
        raise InputError("light and sensitivity must be finite", field="light")
    if np.any(E < 0) or np.any(s < 0):
        raise InputError("light and sensitivity must be non-negative", field="light")
    ws = E * s * grid.step
    total = ws.sum()
    if not total > 0:
        raise InputError("light × sensitivity is zero everywhere on the grid", field="light")
    return ws / total


def _on_grid(values, grid: WavelengthGrid, what: str, field: str) -> np.ndarray:
    """``values`` as a float64 array of one sample per grid wavelength, or an InputError naming ``field``."""
    out = np.asarray(values, np.float64)
    if out.shape != (grid.size,):
        raise InputError(f"{what} has shape {out.shape}, the grid needs ({grid.size},)", field=field)
    return out


def light_spectrum(light="D65", grid: WavelengthGrid = DEFAULT_GRID) -> Float[np.ndarray, "wl"]:
    """A light given as a CIE illuminant name / CCT, or an array on ``grid``."""
    if isinstance(light, (str, int, float)) and not isinstance(light, bool):
        from jkatana.spectral.colorimetry import illuminant

        return illuminant(light, grid)
    return _on_grid(light, grid, "light spectrum", "light")


def _read_curve(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths nm, values) from a CSV (two columns, optional header) or JSON file."""

    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path, field="camera") from None
    if path.suffix.lower() == ".json":
        from jkatana.io.jsonfile import read_json

        doc = read_json(path, "a camera sensitivity file")
        if not isinstance(doc, dict):
            raise InputError("top level must be an object with 'wavelength' and 'sensitivity'", path=path)
        wl = doc.get("wavelength", doc.get("wavelengths"))
        val = doc.get("sensitivity", doc.get("values"))
        if wl is None or val is None:
            raise InputError("needs 'wavelength' and 'sensitivity' arrays", path=path, field="sensitivity")
        try:
            wl, val = np.asarray(wl, np.float64), np.asarray(val, np.float64)
        except (TypeError, ValueError):
            raise InputError("'wavelength' and 'sensitivity' must be arrays of numbers", path=path,
                             field="sensitivity") from None
    else:
        rows = []
        for i, line in enumerate(text.splitlines(), start=1):
            parts = [c.strip() for c in line.replace(";", ",").split(",") if c.strip()]
            if not parts or parts[0].startswith("#"):
                continue
            try:
                rows.append([float(parts[0]), float(parts[1])])
            except (ValueError, IndexError):
                if rows:
                    raise InputError(f"expected 'wavelength,value', got {line!r}", path=path,
                                     row=i) from None
        if not rows:
            raise InputError("no 'wavelength,value' rows", path=path)
        wl, val = np.asarray(rows).T
    if wl.ndim != 1 or wl.shape != val.shape or wl.size < 2:
        raise InputError(f"wavelength {wl.shape} and sensitivity {val.shape} must be equal-length 1-D arrays",
                         path=path, field="sensitivity")
    if not (np.all(np.isfinite(wl)) and np.all(np.isfinite(val)) and np.all(np.diff(wl) > 0)):
        raise InputError("wavelengths must be finite and increasing, values finite", path=path,
                         field="sensitivity")
    return wl, val


def _band(spec: str, grid: WavelengthGrid) -> np.ndarray:
    """A box band ``band:LO-HI`` (nm): sensitivity 1 inside [LO, HI], 0 outside."""
    try:
        lo, hi = (float(v) for v in spec.split(":", 1)[1].split("-"))
    except ValueError:
        raise InputError(f"expected 'band:LO-HI' in nm, got {spec!r}", field="camera") from None
    wl = np.asarray(grid.wavelengths, np.float64)
    out = ((wl >= lo - 1e-9) & (wl <= hi + 1e-9)).astype(np.float64)
    if not out.any():
        raise InputError(f"band {spec!r} holds no wavelength of the grid {wl[0]:g}–{wl[-1]:g} nm", field="camera")
    return out


def camera_sensitivity(camera=DEFAULT_CAMERA, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """One channel's relative sensitivity on ``grid``, from any of the forms a fit accepts.

    - ``"NAME"`` — the green channel of a colour-science camera
      (``colour.MSDS_CAMERA_SENSITIVITIES``, e.g. ``"Nikon 5100 (NPL)"``);
      ``"NAME:red"`` / ``"NAME:green"`` / ``"NAME:blue"`` chooses the channel;
    - ``"band:LO-HI"`` — a box band in nm (a spectral band, e.g. a
      monochromator or filter measurement);
    - a path to a CSV (``wavelength,value`` rows, optional header) or a JSON
      file (``{"wavelength": [...], "sensitivity": [...]}``), resampled onto
      the grid without extrapolation;
    - a ``(wl,)`` array on the grid.
    """
    if isinstance(camera, (str, Path)):
        text = str(camera)
        if text.lower().startswith("band:"):
            return _band(text, grid)
        path = Path(text)
        if path.suffix.lower() in (".csv", ".json", ".txt"):
            wl, val = _read_curve(path)
            out = resample(wl, val, grid, name=f"camera {path}")
            return np.clip(out, 0.0, None)
        name, _, channel = text.rpartition(":")
        if name and channel.lower() in ("red", "green", "blue"):
            return green_sensitivity(grid, name, channel.lower())
        return green_sensitivity(grid, text)
    return _on_grid(camera, grid, "camera sensitivity", "camera")


__all__ = ["DEFAULT_CAMERA", "green_sensitivity", "band_weights", "light_spectrum", "camera_sensitivity"]

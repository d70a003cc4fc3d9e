"""Synthetic goniometer that writes real RAW files (DNG) and their manifest.

:func:`simulate_campaign` renders one small Bayer frame per capture of a
protocol, writes it as a DNG (Adobe DNG Specification 1.4: a CFA TIFF with
``DNGVersion``, ``CFARepeatPatternDim``/``CFAPattern`` RGGB,
``BlackLevelRepeatDim``/``BlackLevel`` per CFA position, ``WhiteLevel``,
``ExposureTime``; written with tifffile, Gohlke) that LibRaw/rawpy opens like
a camera's file, and writes the capture manifest
(:mod:`jkatana.measure.manifest`) beside them. ``jkatana measure`` then reads
the campaign back exactly as it would read a real one.

The frame: the left half shows the hiraji, the right half the hamon (each a
uniform patch at the model's green value ρ, :func:`~jkatana.measure.synthetic.green_values`;
red and blue photosites see the same model through the camera's red and blue
curves, times ``Sensor.rb_gains``), with one ROI inset in each half. Photosite values, in DN:

    f  = ρ · t / gain                       (fraction of full scale; gain: manifest column)
    DN = black[c] + (white − black[c]) · f'  + read noise,  rounded, clipped to [0, white]

with f' = Poisson(f · full_well) / full_well when photon noise is asked for
(``full_well_e``), else f. Exposure t is chosen per capture from a 1/3-stop
ladder (1/8000 s … 30 s) so that the brighter region fills ``fill`` of full
scale, as an operator bracketing by hand would; a fixed ``exposure_s`` can
be forced instead (and then highlights may clip — saturation is flagged by
``measure``).

Effects, each only when asked (defaults: none): photon noise
(``full_well_e``), read noise (``read_noise_dn``), 14-bit quantisation and
clipping (``bits=14``; the default 16-bit container quantises at 1/60000 of
full scale, below any noise of interest), angle jitter, tilt, stray-light
floor (:mod:`jkatana.measure.synthetic` for their definitions).

Every capture draws from its own random stream ``(seed, index)``, so a run
is reproducible and resumable: with ``resume=True`` captures already written
are kept, once verified. Each capture is written atomically, and its SHA-256
then appended to ``raw/SHA256SUMS`` (the format of ``sha256sum``, which can
check it); a resume keeps a capture only when its bytes still have the
recorded digest, and redoes the others (a capture with no record: the run was
stopped between the two; one that differs: truncated or changed since, as a
crash can leave a file whose rename reached the disk before its data). The
manifest (and ``truth.csv``, the expected noiseless table with the predicted
standard errors) is written last and atomically, with ``SHA256SUMS`` rewritten
in capture order.
"""

from __future__ import annotations

import dataclasses
import fractions
import json
import math
from pathlib import Path
from typing import Callable

import numpy as np

from jkatana.errors import InputError
from jkatana.io.atomic import atomic_path, write_text
from jkatana.measure.camera import DEFAULT_CAMERA
from jkatana.measure.manifest import manifest_csv
from jkatana.measure.protocol import as_pairs
from jkatana.measure.synthetic import capture_id, green_values, true_angles
from jkatana.measure.table import MeasurementTable, check_angles, write_table
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid

#: Canon EOS 40D full frame (the paper's camera; 10.1 Mpixel).
EOS40D_SIZE = (3888, 2592)


@dataclasses.dataclass(frozen=True)
class Sensor:
    """The synthetic camera.

    **Arguments:**

    - `width`, `height`: frame size in photosites (even, at least 24; default 64×64).
    - `bits`: 16 (default, effectively unquantised) or 14 (the EOS 40D).
    - `black`: black level per RGGB position; None → 4096·(1, 1.0005, 0.9995, 1)
      at 16 bits, 1024·(…) at 14 bits (slightly different per channel, as in real cameras).
    - `full_well_e`: electrons at full scale; photon noise when set.
    - `read_noise_dn`: Gaussian read noise (DN); 0 = none.
    - `gain`: camera units per (full scale per second), written to the manifest.
    - `rb_gains`: sensitivity of the red and blue photosites relative to green
      (so that a decoder that wrongly averaged them in would be caught).
    """

    width: int = 64
    height: int = 64
    bits: int = 16
    black: tuple[int, int, int, int] | None = None
    full_well_e: float | None = None
    read_noise_dn: float = 0.0
    gain: float = 1.0e4
    rb_gains: tuple[float, float] = (0.5, 0.4)

    def __post_init__(self):
        if self.width < 24 or self.height < 24 or self.width % 2 or self.height % 2:
            raise InputError(f"frame must be even and at least 24×24 (LibRaw refuses frames under 22 "
                             f"photosites a side), got {self.width}×{self.height}", field="size")
        if self.bits not in (12, 14, 16):
            raise InputError(f"bits must be 12, 14 or 16, got {self.bits}", field="bits")
        if self.full_well_e is not None and not self.full_well_e > 0:
            raise InputError("full well must be > 0 electrons", field="full_well_e")
        if not (self.read_noise_dn >= 0 and math.isfinite(self.read_noise_dn)):
            raise InputError("read noise must be >= 0", field="read_noise_dn")

    @property
    def white(self) -> int:
        return 2 ** self.bits - 1

    @property
    def blacks(self) -> tuple[int, int, int, int]:
        if self.black is not None:
            return tuple(int(b) for b in self.black)
        base = 2 ** (self.bits - 4)
        return (base, base + base // 2048 + 1, base - base // 2048 - 1, base)

    def rois(self) -> dict[str, tuple[int, int, int, int]]:
        """ROI per region: hiraji inset in the left half, hamon in the right half (even origins)."""
        m = max(2, (min(self.width, self.height) // 16) // 2 * 2)
        half = self.width // 2
        w = (half - 2 * m) // 2 * 2
        h = (self.height - 2 * m) // 2 * 2
        return {"hiraji": (m, m, w, h), "hamon": (half + m, m, w, h)}

    def predicted_sigma(self, value, exposure_s, n_pixels) -> np.ndarray | float:
        """Standard error of the ROI mean (camera units) this sensor should show."""
        f = np.asarray(value, np.float64) * exposure_s / self.gain
        span = self.white - np.mean(self.blacks)
        var = (self.read_noise_dn ** 2 + 1.0 / 12.0) / span ** 2
        if self.full_well_e:
            var = var + np.clip(f, 0, None) / self.full_well_e
        return np.sqrt(var / n_pixels) * self.gain / exposure_s


#: 1/3-stop shutter ladder from 1/8000 s to 30 s.
SHUTTER_LADDER = tuple(2.0 ** (k / 3.0) for k in range(-39, 15))


def auto_exposure(peak_value: float, gain: float, fill: float) -> float:
    """The longest ladder exposure t with peak·t/gain ≤ fill (≥ 1/8000 s)."""
    best = SHUTTER_LADDER[0]
    for t in SHUTTER_LADDER:
        if peak_value * t / gain <= fill:
            best = t
    return best


def render_frame(values: dict[str, float], exposure_s: float, sensor: Sensor,
                 rng: np.random.Generator | None = None,
                 rb_ratio: dict[str, tuple[float, float]] | None = None) -> np.ndarray:
    """One RGGB frame (uint16 DN): hiraji value on the left half, hamon on the right.

    ``values`` are the green values ρ per region; red and blue photosites get
    ρ·ratio·``sensor.rb_gains`` with ``rb_ratio[region] = (ρR/ρG, ρB/ρG)``
    (default 1: grey).
    """
    H, W = sensor.height, sensor.width
    f = np.empty((H, W), np.float64)
    for region, cols in (("hiraji", np.s_[: W // 2]), ("hamon", np.s_[W // 2:])):
        g = values.get(region, 0.0) * exposure_s / sensor.gain
        ratio_r, ratio_b = (rb_ratio or {}).get(region, (1.0, 1.0))
        patch = np.full((H, f[:, cols].shape[1]), g)
        patch[0::2, 0::2] *= ratio_r * sensor.rb_gains[0]  # R at (even, even) of RGGB
        patch[1::2, 1::2] *= ratio_b * sensor.rb_gains[1]  # B at (odd, odd)
        f[:, cols] = patch
    if sensor.full_well_e:
        rng = np.random.default_rng(0) if rng is None else rng
        f = rng.poisson(np.clip(f, 0, None) * sensor.full_well_e) / sensor.full_well_e
    black = np.empty((H, W), np.float64)
    b = sensor.blacks
    black[0::2, 0::2], black[0::2, 1::2], black[1::2, 0::2], black[1::2, 1::2] = b
    dn = black + (sensor.white - black) * f
    if sensor.read_noise_dn:
        rng = np.random.default_rng(0) if rng is None else rng
        dn = dn + rng.normal(0.0, sensor.read_noise_dn, dn.shape)
    return np.clip(np.rint(dn), 0, sensor.white).astype(np.uint16)


def write_dng(path: str | Path, image: np.ndarray, *, black=(0, 0, 0, 0), white: int = 65535,
              exposure_s: float | None = None, model: str = "jkatana synthetic goniometer") -> Path:
    """Write a Bayer (RGGB) uint16 mosaic as a minimal DNG 1.4 that LibRaw reads (atomic)."""
    import tifffile

    image = np.ascontiguousarray(image, np.uint16)
    if image.ndim != 2:
        raise InputError(f"a CFA mosaic is 2-D, got shape {image.shape}", path=path)
    if min(image.shape) < 22:
        raise InputError(f"LibRaw refuses frames under 22 photosites a side, got {image.shape}", path=path)
    identity = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)  # ColorMatrix1 = I (SRATIONAL)
    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),            # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),            # DNGBackwardVersion
        (50708, "s", 0, model, True),                   # UniqueCameraModel
        (271, "s", 0, "jkatana", True),                 # Make
        (272, "s", 0, model, True),                     # Model
        (33421, "H", 2, (2, 2), True),                  # CFARepeatPatternDim
        (33422, "B", 4, (0, 1, 1, 2), True),            # CFAPattern: R G / G B
        (50713, "H", 2, (2, 2), True),                  # BlackLevelRepeatDim
        (50714, "H", 4, tuple(int(b) for b in black), True),  # BlackLevel per CFA position
        (50717, "H", 1, int(white), True),              # WhiteLevel
        (50721, "2i", 9, identity, True),               # ColorMatrix1
        (50778, "H", 1, 21, True),                      # CalibrationIlluminant1 = D65
    ]
    if exposure_s is not None:
        fr = fractions.Fraction(exposure_s).limit_denominator(1_000_000)
        tags.append((33434, "2I", 1, (fr.numerator, fr.denominator), True))  # ExposureTime
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, image, photometric=32803, subfiletype=0, extratags=tags, metadata=None)
    return Path(path)


#: The file beside the captures that records what produced them (``resume`` compares it).
FINGERPRINT = ".simulation-inputs.json"
#: In ``raw/``: one ``<sha256>  <file name>`` line per capture written (``sha256sum`` format; ``resume`` verifies).
CHECKSUMS = "SHA256SUMS"


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _read_checksums(path: Path) -> dict[str, str]:
    """``{file name: sha256}`` of a ``SHA256SUMS`` file; a malformed line (cut short by a kill) is no record."""
    import re

    line_re = re.compile(r"^([0-9a-f]{64})  ([^/\\]+)$")
    out = {}
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return out
    for line in text.split("\n"):
        m = line_re.match(line)
        if m:
            out[m.group(2)] = m.group(1)
    return out


def _jsonable(value):
    """Inputs as JSON values; arrays (a custom light or camera) by their SHA-256."""
    import hashlib

    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    if isinstance(value, Path):
        return str(value)
    arr = np.ascontiguousarray(np.asarray(value, np.float64))
    return {"array_sha256": hashlib.sha256(arr.tobytes()).hexdigest(), "shape": list(arr.shape)}


def _fingerprint(**inputs) -> dict:
    """Every input that changes a capture, the truth table or the manifest, as comparable JSON."""
    return json.loads(json.dumps(_jsonable(inputs), sort_keys=True))


def _check_resume(stamp: Path, raw_dir: Path, inputs: dict) -> None:
    """Resume only captures made from the same inputs; say which inputs differ otherwise."""
    if not stamp.is_file():
        if raw_dir.is_dir() and any(raw_dir.glob("*.dng")):
            raise InputError(f"cannot resume: {raw_dir} holds captures but no record of the inputs that made "
                             f"them ({FINGERPRINT}); simulate again without --resume", path=stamp, field="resume")
        return
    try:
        old = json.loads(stamp.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        raise InputError("cannot resume: the record of the inputs is unreadable; simulate again without "
                         "--resume", path=stamp, field="resume") from None
    changed = sorted(k for k in set(old) | set(inputs) if old.get(k) != inputs.get(k)) \
        if isinstance(old, dict) else ["(all)"]
    if changed:
        raise InputError(f"cannot resume: the captures there were simulated with other {', '.join(changed)}; "
                         "simulate again without --resume, or into another folder", path=stamp, field="resume")


def simulate_campaign(out_dir: str | Path, protocol=None, *, regions=("hiraji", "hamon"), params=None,
                      optical_constants: str = "Fe-Johnson", light="D65", camera=DEFAULT_CAMERA,
                      sensor: Sensor | None = None, exposure_s: float | None = None, fill: float = 0.5,
                      tilt_deg: float = 0.0, stray_floor: float = 0.0, angle_jitter_deg: float = 0.0,
                      grid: WavelengthGrid = DEFAULT_GRID, seed: int = 0, resume: bool = False,
                      progress: Callable[[int], None] | None = None) -> dict:
    """Write a synthetic campaign: ``raw/*.dng``, ``manifest.csv``, ``truth.csv``, ``simulation.json``.

    **Arguments:** as :func:`~jkatana.measure.synthetic.simulate_table`, plus

    - `out_dir`: output folder (created).
    - `regions`: which regions to put in each frame's ROIs.
    - `params`: None (paper's), or ``{"hiraji": {...}, "hamon": {...}}``.
    - `sensor`: a :class:`Sensor` (default 64×64, 16-bit, noiseless).
    - `exposure_s`: force one exposure for all captures (else auto, ``fill``).
    - `resume`: keep DNG files already written; they were made from the same inputs (recorded in
      ``.simulation-inputs.json`` before the first capture), else :class:`InputError` naming what changed.
      A kept file must have the SHA-256 recorded in ``raw/SHA256SUMS`` when it was written; any other
      is written again (module docstring).
    - `progress`: called with 1 after each capture.

    **Returns:** a dict with the paths and counts.
    """
    out = Path(out_dir)
    sensor = Sensor() if sensor is None else sensor
    pairs = as_pairs(protocol)
    regions = tuple(regions)
    params = _checked_inputs(pairs, regions, params, fill=fill, stray_floor=stray_floor, tilt_deg=tilt_deg,
                             angle_jitter_deg=angle_jitter_deg, exposure_s=exposure_s)
    ti, tr = true_angles(pairs, tilt_deg=tilt_deg, angle_jitter_deg=angle_jitter_deg,
                         rng=np.random.default_rng([seed, 2 ** 31]))
    kw = dict(optical_constants=optical_constants, light=light, grid=grid)
    truth, ratios = _true_values(pairs, ti, tr, regions, params, camera, stray_floor, kw)
    settings = dict(regions=list(regions), params={r: params.get(r) for r in regions},
                    optical_constants=optical_constants, light=light, camera=camera,
                    sensor=dataclasses.asdict(sensor), exposure_s=exposure_s, fill=fill, tilt_deg=tilt_deg,
                    stray_floor=stray_floor, angle_jitter_deg=angle_jitter_deg, grid=grid.as_dict(), seed=seed)
    inputs = _fingerprint(pairs=[[float(a), float(b)] for a, b in pairs], **settings)
    recorded = _start_raw(out, inputs, resume)
    manifest_rows, truth_rows = _write_captures(out / "raw", pairs, regions, truth, ratios, sensor, exposure_s,
                                                fill, seed, recorded if resume else {}, progress)
    cols = {k: [row[k] for row in truth_rows] for k in truth_rows[0]}
    write_table(MeasurementTable.from_columns(**cols), out / "truth.csv")
    write_text(out / "simulation.json", json.dumps(_simulation_record(len(pairs), settings), indent=2))
    write_text(out / "manifest.csv", manifest_csv(manifest_rows, folder=out))
    return dict(manifest=out / "manifest.csv", truth=out / "truth.csv", captures=len(pairs),
                rows=len(manifest_rows))


def _checked_inputs(pairs, regions: tuple, params, *, fill, stray_floor, tilt_deg, angle_jitter_deg,
                    exposure_s) -> dict:
    """:func:`simulate_campaign`'s inputs checked before any work (:class:`InputError` naming the first
    wrong one); returns the per-region parameters (empty: the paper's)."""
    for row, (a, b) in enumerate(pairs, start=1):
        check_angles(a, b, path="protocol", row=row)
    for r in regions:
        if r not in ("hiraji", "hamon"):
            raise InputError(f"can simulate 'hiraji' and 'hamon', not {r!r}", field="regions")
    if not (0 < fill <= 4):
        raise InputError(f"fill must be in (0, 4], got {fill}", field="fill")
    if not (math.isfinite(stray_floor) and stray_floor >= 0):
        raise InputError(f"stray-light floor must be finite and >= 0, got {stray_floor}", field="stray_floor")
    if not (math.isfinite(tilt_deg) and abs(tilt_deg) < 90):
        raise InputError(f"tilt must be finite and within ±90°, got {tilt_deg}", field="tilt_deg")
    if not (math.isfinite(angle_jitter_deg) and 0 <= angle_jitter_deg <= 90):
        raise InputError(f"angle jitter must be finite and in [0, 90]°, got {angle_jitter_deg}",
                         field="angle_jitter_deg")
    if exposure_s is not None and not (math.isfinite(exposure_s) and exposure_s > 0):
        raise InputError(f"exposure must be finite and > 0 s, got {exposure_s}", field="exposure_s")
    from jkatana.models.bounds import region, region_params

    params = params or {}
    for r, ps in params.items():
        region(r, field="params")
        if r not in regions:
            raise InputError(f"parameters given for {r!r}, a region not simulated (regions: {', '.join(regions)})",
                             field="params")
        if isinstance(ps, dict):  # (a model object is the caller's, already built)
            region_params(r, ps)
    return params


def _true_values(pairs, ti, tr, regions: tuple, params: dict, camera, stray_floor: float, kw: dict):
    """Each region's green value at the true angles (plus the stray-light floor), checked finite, and the
    red/green and blue/green ratios its red and blue photosites see (1 for a camera given as an array)."""
    truth = {r: green_values(ti, tr, r, params.get(r), camera=camera, **kw) + stray_floor for r in regions}
    for r in regions:
        bad = ~np.isfinite(truth[r])
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"the {r} model gives a non-finite value at θi={pairs[i][0]:g}°, θr={pairs[i][1]:g}° "
                             f"(true angles {float(ti[i]):g}°, {float(tr[i]):g}°); check the parameters and "
                             "effects", field=f"params.{r}")
    ratios = {r: (np.ones(len(pairs)), np.ones(len(pairs))) for r in regions}
    if isinstance(camera, str):  # red and blue photosites through the same camera's own curves
        from jkatana.measure.camera import green_sensitivity

        for r in regions:
            rgb = [green_values(ti, tr, r, params.get(r), camera=green_sensitivity(kw["grid"], camera, ch), **kw)
                   + stray_floor for ch in ("red", "blue")]
            safe = np.where(truth[r] > 0, truth[r], 1.0)
            ratios[r] = tuple(np.where(truth[r] > 0, v / safe, 1.0) for v in rgb)
    return truth, ratios


def _start_raw(out: Path, inputs: dict, resume: bool) -> dict:
    """The capture folder ready to write: on a resume the inputs checked against the record and the writers'
    leftover temporaries removed; the inputs' record and the checksums kept so far written. Returns the
    recorded checksums (name → SHA-256; empty without resume)."""
    raw_dir = out / "raw"
    stamp = out / FINGERPRINT
    sums_path = raw_dir / CHECKSUMS
    recorded = {}
    if resume:
        _check_resume(stamp, raw_dir, inputs)
        recorded = _read_checksums(sums_path)
        for tmp in raw_dir.glob(".*.dng"):  # temporaries of a writer killed mid-file (jkatana.io.atomic)
            tmp.unlink(missing_ok=True)
    raw_dir.mkdir(parents=True, exist_ok=True)
    write_text(stamp, json.dumps(inputs, indent=2, sort_keys=True))
    write_text(sums_path, "".join(f"{d}  {n}\n" for n, d in recorded.items()))
    return recorded


def _write_captures(raw_dir: Path, pairs, regions: tuple, truth: dict, ratios: dict, sensor: Sensor,
                    exposure_s, fill: float, seed: int, recorded: dict, progress) -> tuple[list, list]:
    """Each capture's DNG (kept where a resume verifies its recorded digest), its checksum appended as it is
    written, then ``SHA256SUMS`` rewritten in capture order. Returns the manifest's and the truth table's rows."""
    sums_path = raw_dir / CHECKSUMS
    rois = sensor.rois()
    n_green = {r: rois[r][2] * rois[r][3] // 2 for r in regions}
    digests: dict[str, str] = {}
    manifest_rows, truth_rows = [], []
    with open(sums_path, "a", encoding="utf-8") as sums:
        for i, (a, b) in enumerate(pairs):
            values = {r: float(truth[r][i]) for r in regions}
            t = exposure_s if exposure_s is not None else auto_exposure(max(values.values()), sensor.gain, fill)
            cid = capture_id(a, b)
            path = raw_dir / f"{cid}.dng"
            if path.name in recorded and path.is_file() and _sha256(path) == recorded[path.name]:
                digests[path.name] = recorded[path.name]  # verified: the bytes written then
            else:
                rb = {r: (float(ratios[r][0][i]), float(ratios[r][1][i])) for r in regions}
                frame = render_frame(values, t, sensor, np.random.default_rng([seed, i]), rb)
                write_dng(path, frame, black=sensor.blacks, white=sensor.white, exposure_s=t)
                digests[path.name] = _sha256(path)
                sums.write(f"{digests[path.name]}  {path.name}\n")
                sums.flush()  # in the kernel's hands: a killed process loses no line it wrote
            for r in regions:
                manifest_rows.append(dict(file=str(path), region=r, theta_i_deg=a, theta_r_deg=b, roi=[rois[r]],
                                          exposure_s=t, capture=cid, gain=sensor.gain))
                truth_rows.append(dict(capture=cid, region=r, theta_i_deg=a, theta_r_deg=b, value=values[r],
                                       sigma=float(sensor.predicted_sigma(values[r], t, n_green[r])),
                                       n_pixels=n_green[r], exposure_s=t))
            if progress:
                progress(1)
    write_text(sums_path, "".join(f"{digests[n]}  {n}\n" for n in dict.fromkeys(
        f"{capture_id(a, b)}.dng" for a, b in pairs)))
    return manifest_rows, truth_rows


def _simulation_record(captures: int, settings: dict) -> dict:
    """``simulation.json``: the campaign's settings (a light or camera given as an array named so)."""
    light, camera = settings["light"], settings["camera"]
    return dict(
        protocol_captures=captures, regions=settings["regions"], params=settings["params"],
        optical_constants=str(settings["optical_constants"]),
        light=light if isinstance(light, (str, int, float)) else "array",
        camera=camera if isinstance(camera, str) else "array", sensor=settings["sensor"],
        **{k: settings[k] for k in ("exposure_s", "fill", "tilt_deg", "stray_floor", "angle_jitter_deg", "grid",
                                    "seed")},
        note="truth.csv: expected (noiseless) values at the true geometry, with the sensor's predicted "
             "standard errors; manifest.csv: nominal angles")


__all__ = ["Sensor", "EOS40D_SIZE", "simulate_campaign", "write_dng", "render_frame", "auto_exposure",
           "SHUTTER_LADDER"]

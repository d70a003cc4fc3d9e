"""The Mitsuba 3 export checked by rendering it there: ``jkatana export --to mitsuba`` of a scene, rendered by
Mitsuba 3 from the XML it reads, against ``jkatana render``'s reference mode of the same scene.

Both frames are linear Rec. 709 in Mitsuba's film normalisation (jkatana's XYZ × Σȳ Δλ / 106.75, the
convention of :mod:`validation.mitsuba`), compared in CIE ΔE2000 on the object's pixels with the
reference's 99th-percentile luminance to display white on both sides (:func:`validation.mitsuba.compare`).
The jkatana frame is the reference; Mitsuba renders the exported files with its ``direct`` integrator.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from validation.mitsuba import MITSUBA_Y_NORM, compare, mitsuba_variant


def render_exported(xml: Path, *, spp: int, seed: int = 0, variant: str | None = None) -> np.ndarray:
    """Mitsuba 3 renders an exported ``scene.xml`` (``(H, W, 3)`` linear Rec. 709), in a subprocess so that
    an LLVM variant's JIT and memory stay out of the test process."""
    variant = variant or mitsuba_variant()
    out = Path(xml).with_name("mitsuba_frame.npy")
    code = ("import mitsuba as mi, numpy as np, sys; mi.set_variant(sys.argv[1]); "
            "s = mi.load_file(sys.argv[2]); "
            "np.save(sys.argv[3], np.asarray(mi.render(s, spp=int(sys.argv[4]), seed=int(sys.argv[5]))))")
    r = subprocess.run([sys.executable, "-c", code, variant, str(xml), str(out), str(spp), str(seed)],
                       capture_output=True, text=True, timeout=1800)
    if r.returncode != 0:
        raise RuntimeError(f"Mitsuba failed on {xml}:\n{r.stderr[-3000:]}")
    return np.load(out).astype(np.float64)


def render_jkatana(scene, *, spp: int, seed: int = 0, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``jkatana render``'s reference mode of ``scene``: ``(linear Rec. 709 (H, W, 3), object mask)``."""
    from jkatana.render.renderer import prepare, render_view
    from jkatana.spectral.colorimetry import xyz_to_linear_rgb, xyz_weights

    prep = prepare(scene, mode="reference", samples=spp)
    f = render_view(prep, seed=seed, supersample=supersample)
    scale = float(xyz_weights(prep.grid)[:, 1].sum()) / MITSUBA_Y_NORM
    return xyz_to_linear_rgb(np.asarray(f.xyz, np.float64) * scale, "ITU-R BT.709"), np.asarray(f.mask)


def agreement(scene, out_dir: Path, *, spp_mitsuba: int, spp_jkatana: int, seed: int = 0,
              supersample: int = 2) -> dict:
    """Export ``scene`` to ``out_dir`` (new), render both sides, and compare (module docstring): the
    ΔE2000 summary of :func:`validation.mitsuba.compare` plus both frames and the mask."""
    from jkatana.export.mitsuba import export_mitsuba

    export_mitsuba(scene, out_dir, spp=spp_mitsuba)
    rgb_mi = render_exported(Path(out_dir) / "scene.xml", spp=spp_mitsuba, seed=seed)
    rgb_jk, mask = render_jkatana(scene, spp=spp_jkatana, seed=seed, supersample=supersample)
    stats = compare(rgb_jk, rgb_mi, mask, erode=1)
    return {**stats, "mitsuba": rgb_mi, "jkatana": rgb_jk, "mask": mask}

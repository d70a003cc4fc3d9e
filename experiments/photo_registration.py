"""How the map recovered from photos (``jkatana map PHOTO... --mesh``) degrades with the camera's angle,
the number of photos and uneven light.

Photos rendered by Mitsuba 3 (:mod:`validation.photos`: diffuse side light, 4 spp) of blades carrying a
known w; each recovered map scored by :func:`validation.photos.map_errors` (mean |Δw| over the seen texels,
the share of the blade's length where the hamon boundary is within 1 mm) and the registration residual.

1. angle: the whole built-in blade in one photo, 0–30° from the flat's normal (the straight-rectangle
   ``--crop`` path on the same photo beside it);
2. photo count: the three issue cases (one whole photo; omote + ura; three sections) and 2 and 5 sections;
3. unevenness: the lights' and backdrop's radiance falling linearly along the blade to 1 − g at the tip,
   g = 0, 0.3, 0.6 (whole blade, 10°).

Writes ``experiments/photo_registration/results.json`` and ``registration_study.png``. Run from the
checkout: ``.venv/bin/python experiments/photo_registration.py`` (about 10 minutes on 2 cores).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from validation import photos as vp  # noqa: E402

OUT = Path(__file__).resolve().parent / "photo_registration"


def run_case(case, work, **kw):
    from jkatana.errors import InputError
    from jkatana.maps.mosaic import build_map
    from jkatana.maps.photo import read_photo
    from jkatana.maps.surface import blade_surface

    mesh, truth, paths = vp.render_case(case, work, **kw)
    surface = blade_surface(mesh, truth.shape)
    try:
        res = build_map([(str(p), read_photo(p)) for p in paths], surface, progress=False)
    except InputError as err:
        return {"error": str(err), "photos": len(paths)}, paths, truth, surface
    e = vp.map_errors(res.map.w, truth, res.seen, surface)
    e["residual_px"] = max(p["residual_px"] for p in res.report["photos"])
    e["photos"] = len(paths)
    e["summary"] = res.summary
    return e, paths, truth, surface


def main() -> None:
    OUT.mkdir(exist_ok=True)
    results = {"angle": [], "count": [], "unevenness": []}
    with tempfile.TemporaryDirectory() as tmp:
        for angle in (0.0, 5.0, 10.0, 15.0, 20.0, 30.0):
            work = Path(tmp) / f"angle{angle:g}"
            e, paths, truth, surface = run_case("whole", work, tilt_deg=angle)
            e["angle_deg"] = angle
            e["crop"] = vp.crop_comparison(paths[0], truth, surface)
            results["angle"].append(e)
            print("angle", angle, e, flush=True)
        for case in ("whole", "sides", "sections"):
            e, paths, truth, surface = run_case(case, Path(tmp) / case)
            e["case"] = case
            if case == "whole":
                e["crop"] = vp.crop_comparison(paths[0], truth, surface)
            results["count"].append(e)
            print(case, e, flush=True)
        for n in (2, 5):
            shots = vp.section_shots(n, spp=4)
            e, *_ = run_case("sections", Path(tmp) / f"sections{n}", shots=shots)
            e["case"] = f"sections{n}"
            results["count"].append(e)
            print(n, e, flush=True)
        for g in (0.0, 0.3, 0.6):
            e, *_ = run_case("whole", Path(tmp) / f"uneven{g:g}", unevenness=g)
            e["unevenness"] = g
            results["unevenness"].append(e)
            print("uneven", g, e, flush=True)
    (OUT / "results.json").write_text(json.dumps(results, indent=1))
    plot(results)


def plot(results) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(14, 4.2))
    a = [r for r in results["angle"] if "error" not in r]
    x = [r["angle_deg"] for r in a]
    ax[0].plot(x, [r["mean_abs_dw"] for r in a], "o-", label="mean |Δw|, registered")
    ax[0].plot(x, [r["crop"]["mean_abs_dw"] for r in a], "s--", label="mean |Δw|, --crop")
    ax[0].plot(x, [1 - r["boundary_within_1mm"] for r in a], "^-", label="length with boundary > 1 mm off")
    ax[0].plot(x, [r["residual_px"] / 10 for r in a], "x:", label="outline residual / 10 px")
    ax[0].axhline(0.05, color="grey", lw=0.8)
    ax[0].set_xlabel("camera angle from the flat's normal (°)")
    ax[0].set_title("whole blade, one photo")
    ax[0].legend(fontsize=7)
    c = [r for r in results["count"] if "error" not in r]
    labels = [f"{r['case']}\n({r['photos']})" for r in c]
    ax[1].bar(np.arange(len(c)) - 0.2, [r["mean_abs_dw"] for r in c], 0.4, label="mean |Δw|")
    ax[1].bar(np.arange(len(c)) + 0.2, [1 - r["boundary_within_1mm"] for r in c], 0.4,
              label="length with boundary > 1 mm off")
    ax[1].set_xticks(np.arange(len(c)), labels, fontsize=7)
    ax[1].axhline(0.05, color="grey", lw=0.8)
    ax[1].set_title("photo count")
    ax[1].legend(fontsize=7)
    u = [r for r in results["unevenness"] if "error" not in r]
    g = [r["unevenness"] for r in u]
    ax[2].plot(g, [r["mean_abs_dw"] for r in u], "o-", label="mean |Δw|")
    ax[2].plot(g, [1 - r["boundary_within_1mm"] for r in u], "^-", label="length with boundary > 1 mm off")
    ax[2].axhline(0.05, color="grey", lw=0.8)
    ax[2].set_xlabel("light falling to 1 − g at the tip")
    ax[2].set_title("uneven light (whole blade, 10°)")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "registration_study.png", dpi=110)


if __name__ == "__main__":
    main()

"""Turntable of the blade under three environments, with the reference renderer's batch API.

    python experiments/turntable.py [-o out/turntable] [--frames 24] [--resolution 400x300]
                                    [--samples 32] [--mode reference] [--env sky forest studio]

For each environment the built-in blade (``builtin:katana``, its procedural
reflectance map, iron after Johnson & Christy 1974) is rendered from
``--frames`` camera azimuths evenly around it (:func:`jkatana.render.batch.plan_batch`,
views × 1 lighting), as EXR (linear XYZ) + PNG (sRGB) per frame, through
:func:`jkatana.render.batch.run_batch_serial`: frames already finished are
skipped, so an interrupted run resumes where it stopped. At the end a contact
sheet (rows: environments, columns: up to 8 evenly spaced frames) and a timing
table are written.

Environments (``--env``; names or paths):

- ``sky``: the Hosek–Wilkie (2012, 2013) spectral sky, low afternoon sun (the demo's);
- ``forest``, ``studio``, ``city``, … : Poly Haven RGB EXR maps (CC0, Greg Zaal) in
  ``shared_data("envmaps")``, upsampled to spectra by the scene's default method;
- any other ``.exr``/``.hdr`` path.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path
from jkatana.shared import shared_data

ENV_DIR = shared_data("envmaps")


def environment(name: str) -> dict:
    """The scene's ``[environment]`` table for an environment name or file path."""
    if name == "sky":
        return {"type": "sky", "elevation_deg": 14.0, "azimuth_deg": 195.0, "turbidity": 3.0,
                "albedo": 0.1, "resolution": [256, 512]}
    p = Path(name)
    if not p.suffix:
        p = ENV_DIR / f"{name}.exr"
    if not p.is_file():
        raise SystemExit(f"turntable: environment {name!r}: file not found: {p}")
    return {"type": "hdr" if p.suffix.lower() == ".hdr" else "exr", "path": str(p.resolve())}


def contact_sheet(rows: list[list[Path]], labels: list[str], path: Path) -> Path:
    """Frames in a grid (one row per environment) as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    ncol = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.2 * ncol, 1.8 * len(rows)), dpi=100, squeeze=False)
    for i, (frames, label) in enumerate(zip(rows, labels)):
        for j in range(ncol):
            ax = axes[i][j]
            ax.set_axis_off()
            if j < len(frames):
                ax.imshow(mpimg.imread(frames[j]))
        axes[i][0].set_title(label, fontsize=8, loc="left")
    fig.tight_layout()
    from jkatana.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-o", "--output", default="out/turntable")
    p.add_argument("--frames", type=int, default=24, help="camera azimuths per environment")
    p.add_argument("--resolution", default="400x300", help="WxH")
    p.add_argument("--samples", type=int, default=32, help="samples per pixel")
    p.add_argument("--mode", default="reference", help="reference | paper | prefiltered | lowrank")
    p.add_argument("--env", nargs="+", default=["sky", "forest", "studio"])
    p.add_argument("--exposure", default="auto",
                   help='"auto" (per frame) or a number multiplying XYZ (fixed: no flicker along the turntable)')
    p.add_argument("--force", action="store_true", help="re-render finished frames")
    args = p.parse_args(argv)
    try:
        from jkatana.render.batch import plan_batch, run_batch_serial, summary_table
        from jkatana.render.scenefile import DEMO_SCENE, scene_from_dict
    except ImportError as err:
        print(f"turntable: needs the reference renderer's batch API (jkatana.render.batch: plan_batch, "
              f"run_batch_serial; jkatana.render.scene) which is not available here ({err})", file=sys.stderr)
        return 2
    try:
        w, h = (int(x) for x in args.resolution.lower().split("x"))
    except ValueError:
        print(f"turntable: --resolution must be WxH, got {args.resolution!r}", file=sys.stderr)
        return 2
    out = Path(args.output)
    sheet_rows, labels, timing = [], [], {}
    for name in args.env:
        raw = copy.deepcopy(DEMO_SCENE)
        raw["environment"] = environment(name)
        raw["camera"]["resolution"] = [w, h]
        raw["render"] = {"mode": args.mode, "samples": args.samples}
        raw["film"] = dict(raw.get("film", {}),
                           exposure=args.exposure if args.exposure == "auto" else float(args.exposure))
        stem = Path(name).stem
        raw["output"] = {"directory": str(out / stem), "name": stem}
        scene = scene_from_dict(raw)
        jobs = plan_batch(scene, views=args.frames, lights=1)
        print(f"turntable: {stem}: {len(jobs)} frames ({w}×{h}, {args.samples} spp, {args.mode})", file=sys.stderr)
        t0 = time.perf_counter()
        results = run_batch_serial(scene, jobs, force=args.force)
        timing[stem] = {"wall_s": time.perf_counter() - t0, "frames": results}
        print(summary_table(results), file=sys.stderr)
        step = max(1, len(jobs) // 8)
        sheet_rows.append([Path(j.stem).with_suffix(".png") for j in jobs[::step]][:8])
        labels.append(f"{stem} ({args.mode}, {args.samples} spp)")
    from jkatana.io.atomic import write_text

    sheet = contact_sheet(sheet_rows, labels, out / "contact_sheet.png")
    write_text(out / "timing.json", json.dumps(timing, indent=1, default=float))
    print(f"turntable: contact sheet {sheet}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""CLI of the shape stage: ``jkatana shape`` (scans → merged, Bezier-smoothed mesh)."""

from __future__ import annotations

import argparse
import sys

SHAPE_HELP = "Scan(s) → registered, merged, Bezier-smoothed blade mesh with UVs (PLY/GLB)."


def shape_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scans", nargs="*", help="range sections in order (PLY, OBJ, XYZ); or --simulate")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply, .glb or .obj)")
    p.add_argument("--simulate", action="store_true",
                   help="scan the built-in blade with the simulated 640×480 scanner")
    p.add_argument("--blade", action="store_true",
                   help="write the parametric built-in blade itself (no scanning)")
    p.add_argument("--scan-resolution", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--degree", type=int, default=3)
    p.add_argument("--patches", type=int, nargs=2, default=(40, 6), metavar=("ALONG", "ACROSS"))
    p.add_argument("--smoothness", type=float, default=1e-5)
    p.add_argument("--max-points", type=int, default=400000,
                   help="random subset of the merged points used by the fit")
    p.add_argument("--height-field", action="store_true",
                   help="scans are not a katana: fit one height field over their principal plane")


def shape_run(args: argparse.Namespace) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from tqdm import tqdm

    from jkatana.errors import InputError
    from jkatana.shape.katana import default_blade, export_blade
    from jkatana.shape.reconstruct import (point_error, reconstruct_blade, smooth_height_field,
                                           surface_error)
    from jkatana.shape.scans import merge, read_scan, register_sections, simulate_scans

    from jkatana.io.limits import number, numbers, require_memory
    from jkatana.io.outputs import Output, check_outputs

    sw, sh = numbers(args.scan_resolution, "--scan-resolution", lo=8, hi=2 ** 16, integer=True)
    number(args.seed, "--seed", lo=0, hi=2 ** 32 - 1, integer=True)
    number(args.degree, "--degree", lo=1, hi=7, integer=True)
    pa, pc = numbers(args.patches, "--patches", lo=1, hi=4096, integer=True)
    number(args.smoothness, "--smoothness", lo=0)
    number(args.max_points, "--max-points", lo=16, hi=2 ** 31, integer=True)
    budget = getattr(args, "max_memory", None)
    if args.simulate:
        # about 40 sections (both faces), each a W×H range image → points (float64 xyz, with copies)
        require_memory(40 * sw * sh * 3 * 8 * 4, "--scan-resolution", f"simulated {sw}×{sh} scans", budget)
    n_ctrl = (pa * args.degree + 1) * (pc * args.degree + 1)
    # per fitted point its (degree+1)² Bernstein weights and indices; per control point the CG vectors
    require_memory(args.max_points * (args.degree + 1) ** 2 * 16 + n_ctrl * 8 * 32, "--patches",
                   f"{pa}×{pc} patches of degree {args.degree} fitted to {args.max_points} points", budget)
    check_outputs([Output(args.output, "--output", (".ply", ".glb", ".obj"))], inputs=args.scans)
    if args.blade:
        export_blade(default_blade(), args.output)
        print(f"wrote {args.output}", file=sys.stderr)
        return 0
    truth = None
    if args.simulate:
        truth = default_blade()
        scans = simulate_scans(truth, resolution=tuple(args.scan_resolution), seed=args.seed)
    else:
        if not args.scans:
            raise InputError("give scan files or --simulate", field="scans")
        scans = []
        for i, path in enumerate(tqdm(args.scans, desc="reading scans", file=sys.stderr)):
            s = read_scan(path)
            s.section = i
            scans.append(s)
    regs = register_sections(scans) if len(scans) > 1 else None
    for s, r in zip(scans, regs or []):
        if not r.converged:
            print(f"warning: {s.name or s.section}: ICP stopped after {r.iterations} iterations "
                  f"(overlap RMS {r.rms * 1e3:.3f} mm)", file=sys.stderr)
    pts = merge(scans, regs)
    rng = np.random.default_rng(args.seed)
    if len(pts) > args.max_points:
        pts = pts[rng.choice(len(pts), args.max_points, replace=False)]
    if args.height_field:
        mesh, _, info = smooth_height_field(pts, degree=args.degree, patches=tuple(args.patches),
                                            smoothness=args.smoothness)
        infos = {"surface": info}
    else:
        rec = reconstruct_blade(pts, degree=args.degree, patches=tuple(args.patches),
                                smoothness=args.smoothness)
        mesh, infos = rec.mesh, rec.info
    for name, info in infos.items():
        state = "converged" if info.converged else "NOT converged"
        print(f"{name}: {info.n_points} points, {info.n_control} control points, CG {state} in "
              f"{info.iterations} iterations, fit RMS {info.rms * 1e3:.4f} mm", file=sys.stderr)
    if truth is not None:
        raw = point_error(pts[:: max(1, len(pts) // 20000)], truth)
        sm = surface_error(mesh, truth)
        print(f"vs true surface: raw merged scan RMS {raw['rms'] * 1e3:.4f} mm, max "
              f"{raw['max'] * 1e3:.3f} mm; smoothed RMS {sm['rms'] * 1e3:.4f} mm, Hausdorff "
              f"{sm['hausdorff'] * 1e3:.3f} mm", file=sys.stderr)
    export_blade(mesh, args.output)
    print(f"wrote {args.output}: {len(mesh.faces)} triangles", file=sys.stderr)
    return 0

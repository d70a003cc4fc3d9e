"""CLI of the shape stage: ``jkatana shape``.

Any mesh (a user's scan) → metres, blade frame, cleaned, with UVs
(:mod:`jkatana.shape.mesh`); or, chosen explicitly, the built-in katana
(``--blade``), its simulated scan (``--simulate``), a fit of range sections
to the built-in katana's outline (``--katana-fit``) or a height field over one
view (``--height-field``).
"""

from __future__ import annotations

import argparse
import sys

SHAPE_HELP = ("Any mesh (OBJ/PLY/GLB/STL) → metres, blade frame, cleaned, with UVs; or the built-in katana "
              "(--blade, --simulate, --katana-fit).")

SHAPE_EPILOG = """\
A mesh file (the default): the units are guessed from its size and stated (OBJ, PLY and STL carry
none; --units sets them); a blade-like mesh (one axis at least 5x the others) is turned into the
built-in blade's frame (length along +X, tip at +X, back/mune toward +Y, edge/ha toward -Y, flats
facing +-Z, machi at the origin) unless --keep-frame; vertices are merged, degenerate faces dropped
and small holes closed; --smooth N runs N Taubin iterations that hold creases; UVs are the blade's
(u along, v across, the same on both flats) or a general xatlas unwrap (--uv). A report
(<output>_shape.json) and a preview (<output>_preview.png) are written beside the mesh.

The built-in katana's reconstruction (--katana-fit, --simulate) assumes a blade with the built-in
katana's outline in its frame and refuses scans that do not fit it.
"""


def shape_add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = SHAPE_EPILOG
    p.add_argument("scans", nargs="*",
                   help="a mesh file (OBJ, PLY, GLB, STL); with --katana-fit or --height-field range "
                        "sections in order (PLY, OBJ, XYZ)")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply, .glb or .obj)")
    g = p.add_argument_group("any mesh")
    g.add_argument("--units", default="auto", choices=("auto", "m", "dm", "cm", "mm", "in"),
                   help="units of the file's numbers (default: guessed from the size and reported)")
    g.add_argument("--keep-frame", action="store_true",
                   help="keep the file's axes (default: a blade-like mesh goes into the blade frame)")
    g.add_argument("--uv", default="auto", choices=("auto", "blade", "xatlas", "none"),
                   help="UVs: blade (u along, v across, per side), xatlas (general unwrap), none; "
                        "auto = blade for a blade, else xatlas")
    g.add_argument("--smooth", type=int, default=0, metavar="N",
                   help="N iterations of Taubin smoothing that hold creases (default 0: none)")
    g.add_argument("--crease-deg", type=float, default=20.0,
                   help="dihedral angle above which an edge is a crease: sharp normals, held by --smooth")
    g.add_argument("--no-clean", action="store_true",
                   help="do not merge vertices, drop degenerate faces or fill holes")
    g.add_argument("--max-hole-edges", type=int, default=32,
                   help="close boundary loops of at most this many edges")
    g.add_argument("--preview", help="preview PNG (default <output>_preview.png)")
    g.add_argument("--report", help="report JSON (default <output>_shape.json)")
    g.add_argument("--credit", default="",
                   help="attribution printed on the preview (e.g. a CC BY scan's author and licence)")
    k = p.add_argument_group("the built-in katana (explicit)")
    k.add_argument("--blade", action="store_true",
                   help="write the parametric built-in blade itself (no scanning)")
    k.add_argument("--nagasa", type=float, default=None, metavar="M",
                   help="with --blade: blade length in metres (straight line machi → tip; default 0.70)")
    k.add_argument("--sori", type=float, default=None, metavar="M",
                   help="with --blade: curvature in metres (the chord's largest distance to the mune; default 0.018)")
    k.add_argument("--simulate", action="store_true",
                   help="scan the built-in blade with the simulated 640×480 scanner and fit it")
    k.add_argument("--katana-fit", action="store_true",
                   help="fit range sections of a blade with the built-in katana's outline, in its frame")
    k.add_argument("--height-field", action="store_true",
                   help="fit one height field over the sections' principal plane (a single view)")
    k.add_argument("--scan-resolution", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    k.add_argument("--seed", type=int, default=0)
    k.add_argument("--degree", type=int, default=3)
    k.add_argument("--patches", type=int, nargs=2, default=(40, 6), metavar=("ALONG", "ACROSS"))
    k.add_argument("--smoothness", type=float, default=1e-5)
    k.add_argument("--max-points", type=int, default=400000,
                   help="random subset of the merged points used by the fit")


def _shape_any_mesh(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from jkatana.errors import InputError
    from jkatana.io.atomic import write_text
    from jkatana.shape.katana import export_blade
    from jkatana.shape.mesh import prepare_mesh, preview_png, read_mesh

    if len(args.scans) != 1:
        raise InputError(f"give one mesh file, got {len(args.scans)} (several range sections: "
                         "--katana-fit or --height-field)", field="scans")
    src = Path(args.scans[0])
    if src.suffix.lower() in (".xyz", ".txt", ".csv", ".pts"):
        from jkatana.shape.scans import read_scan

        read_scan(src)  # names a bad file first
        raise InputError("a point list has no faces: give a mesh, or --katana-fit / --height-field",
                         path=src)
    mesh, rep = prepare_mesh(read_mesh(src), source=src.name, suffix=src.suffix,
                             units=args.units, frame="keep" if args.keep_frame else "auto",
                             clean=not args.no_clean, smooth=args.smooth, crease_deg=args.crease_deg,
                             uv=args.uv, max_hole_edges=args.max_hole_edges)
    out = Path(args.output)
    export_blade(mesh, out)
    stem = out.with_suffix("")
    preview = Path(args.preview) if args.preview else stem.with_name(stem.name + "_preview.png")
    report = Path(args.report) if args.report else stem.with_name(stem.name + "_shape.json")
    preview_png(mesh, preview, title=f"{src.name} ({rep.units} → m)", credit=args.credit)
    write_text(report, json.dumps({**rep.__dict__, "output": str(out), "preview": str(preview)}, indent=1))
    for line in rep.lines():
        print(line, file=sys.stderr)
    print(f"wrote {out}, {report}, {preview}", file=sys.stderr)
    return 0


def shape_run(args: argparse.Namespace) -> int:
    from jkatana.io.limits import number

    # the mesh options, checked whatever the mode (a mode that does not use them still refuses nonsense)
    number(args.smooth, "--smooth", lo=0, hi=10000, integer=True)
    number(args.crease_deg, "--crease-deg", lo=0, hi=180)
    number(args.max_hole_edges, "--max-hole-edges", lo=0, hi=2 ** 20, integer=True)
    if not (args.blade or args.simulate or args.katana_fit or args.height_field):
        return _shape_any_mesh(args)
    import jax

    jax.config.update("jax_enable_x64", True)
    from jkatana.shape.katana import export_blade
    from jkatana.shape.reconstruct import point_error, surface_error

    _check_katana_options(args)
    if args.blade:
        return _shape_builtin(args)
    scans, truth = _scans(args)
    pts = _merged_points(scans, args.max_points, args.seed)
    mesh = _fit_surface(pts, args)
    if truth is not None:
        raw = point_error(pts[:: max(1, len(pts) // 20000)], truth)
        sm = surface_error(mesh, truth)
        print(f"vs true surface: raw merged scan RMS {raw['rms'] * 1e3:.4f} mm, max "
              f"{raw['max'] * 1e3:.3f} mm; smoothed RMS {sm['rms'] * 1e3:.4f} mm, Hausdorff "
              f"{sm['hausdorff'] * 1e3:.3f} mm", file=sys.stderr)
    export_blade(mesh, args.output)
    print(f"wrote {args.output}: {len(mesh.faces)} triangles", file=sys.stderr)
    return 0


def _check_katana_options(args: argparse.Namespace) -> None:
    """The built-in katana's options, the memory its scans and fit need, and the output, checked before any
    work."""
    from jkatana.errors import InputError
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
    if (args.nagasa is not None or args.sori is not None) and not args.blade:
        raise InputError("--nagasa and --sori shape the built-in blade: give them with --blade", field="--nagasa")


def _shape_builtin(args: argparse.Namespace) -> int:
    """``--blade``: the parametric built-in blade itself, shaped by ``--nagasa``/``--sori`` when given."""
    from jkatana.shape.katana import default_blade, export_blade

    if args.nagasa is not None or args.sori is not None:
        import dataclasses

        from jkatana.shape.katana import KatanaSpec, build_blade

        spec = KatanaSpec()
        spec = dataclasses.replace(spec, **{k: v for k, v in (("nagasa", args.nagasa), ("sori", args.sori))
                                            if v is not None})
        export_blade(build_blade(spec), args.output)  # validate() names a bad --nagasa or --sori
        print(f"wrote {args.output}: nagasa {spec.nagasa:g} m, sori {spec.sori:g} m", file=sys.stderr)
        return 0
    export_blade(default_blade(), args.output)
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


def _scans(args: argparse.Namespace):
    """The range sections (read in order, or ``--simulate``'s scans of the built-in blade) and the true blade
    (None unless simulated)."""
    from tqdm import tqdm

    from jkatana.errors import InputError
    from jkatana.shape.katana import default_blade
    from jkatana.shape.scans import read_scan, simulate_scans

    if args.simulate:
        truth = default_blade()
        return simulate_scans(truth, resolution=tuple(args.scan_resolution), seed=args.seed), truth
    if not args.scans:
        raise InputError("give scan files or --simulate", field="scans")
    scans = []
    for i, path in enumerate(tqdm(args.scans, desc="reading scans", file=sys.stderr)):
        s = read_scan(path)
        s.section = i
        scans.append(s)
    return scans, None


def _merged_points(scans, max_points: int, seed: int):
    """The sections registered to each other (ICP; a warning where it stopped short), merged, and a random
    subset of at most ``max_points``."""
    import numpy as np

    from jkatana.shape.scans import merge, register_sections

    regs = register_sections(scans) if len(scans) > 1 else None
    for s, r in zip(scans, regs or []):
        if not r.converged:
            print(f"warning: {s.name or s.section}: ICP stopped after {r.iterations} iterations "
                  f"(overlap RMS {r.rms * 1e3:.3f} mm)", file=sys.stderr)
    pts = merge(scans, regs)
    rng = np.random.default_rng(seed)
    if len(pts) > max_points:
        pts = pts[rng.choice(len(pts), max_points, replace=False)]
    return pts


def _fit_surface(pts, args: argparse.Namespace):
    """The Bezier surface fitted to the points (``--height-field``: one height field; else the katana's
    reconstruction), each fit's summary printed."""
    from jkatana.shape.reconstruct import reconstruct_blade, smooth_height_field

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
    return mesh

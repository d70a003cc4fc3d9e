"""CLI of the maps stage: ``jkatana map PHOTO -o MAP.exr``."""

from __future__ import annotations

import argparse
import sys

MAP_HELP = "Reflectance map (w and per-pixel parameters, EXR) from a diffuse-lit photo of the blade."


def map_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("photo", nargs="*", help="photo under diffuse light (.exr, 16-bit .png/.tif, or camera RAW via rawpy); "
                   "omit with --default; several with --mesh")
    p.add_argument("-o", "--output", required=True, help="output map (.exr)")
    p.add_argument("--default", action="store_true", help="write the procedural default map instead")
    p.add_argument("--crop", type=int, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   help="the blade's rectangle in the photo (rows mune → ha, columns machi → tip)")
    p.add_argument("--flip-v", action="store_true", help="the photo's rows run ha → mune")
    p.add_argument("--dark", type=float, help="luminance at and below which w = 1 (hiraji)")
    p.add_argument("--bright", type=float, help="luminance at and above which w = 0 (hamon)")
    p.add_argument("--hiraji", help="hiraji region fit JSON (chi, mu0); default: the paper's")
    p.add_argument("--hamon", help="hamon region fit JSON (beta, mu1); default: the paper's")
    p.add_argument("--resolution", type=int, nargs=2, default=(256, 1024), metavar=("H", "W"))
    p.add_argument("--aspect", type=float, default=None,
                   help="expected length/width of the cropped blade image; reject others")
    g = p.add_argument_group("photos of the whole blade or its sections, registered on its mesh (jkatana.maps.register)")
    g.add_argument("--mesh", help="the blade's mesh with blade UVs (jkatana shape ... --uv blade): each photo is "
                   "registered on it (its outline fitted by the mesh's silhouette) instead of --crop")
    g.add_argument("--flat", nargs="+", metavar="FLAT",
                   help="flat-field photo(s) (a grey card under the same light and camera): one, or one per photo; "
                        "default: a smooth fit of the background's brightness")
    g.add_argument("--focal-mm", type=float, nargs="+", metavar="MM",
                   help="focal length from the photos' EXIF (one, or one per photo); needs --sensor-mm")
    g.add_argument("--sensor-mm", type=float, default=None, help="sensor width in mm (36 for full frame)")
    g.add_argument("--side", nargs="+", choices=("omote", "ura", "auto"), metavar="SIDE",
                   help="the face each photo shows (omote, ura or auto; one, or one per photo); default: auto")
    g.add_argument("--points", help='JSON of clicked points where automatic registration fails: {"PHOTO_NAME": '
                   '{"side": "omote", "points": [[x, y, u, v], ...]}} (pixels; blade UVs), 3 or more per photo')
    g.add_argument("--confidence", help="per-texel confidence EXR (default <output>_confidence.exr)")
    g.add_argument("--preview", help="preview PNG with the mesh drawn over each photo (default <output>_preview.png)")
    g.add_argument("--report", help="registration report JSON (default <output>_registration.json)")


def map_run(args: argparse.Namespace) -> int:
    from jkatana.errors import InputError
    from jkatana.maps.photo import load_region_parameters, map_from_photo, read_photo
    from jkatana.maps.reflectance_map import default_map

    from jkatana.io.limits import number, numbers, require_memory
    from jkatana.io.outputs import Output, check_outputs

    h, w = numbers(args.resolution, "--resolution", lo=2, hi=2 ** 16, integer=True)
    number(args.aspect, "--aspect", lo=0, lo_open=True, hi=1e3)
    number(args.dark, "--dark", lo=0)
    number(args.bright, "--bright", lo=0)
    if args.dark is not None and args.bright is not None and not args.bright > args.dark:
        raise InputError(f"--bright must be above --dark, got {args.dark:g} {args.bright:g}", field="--bright")
    numbers(args.crop, "--crop", lo=0, hi=2 ** 20, integer=True)
    # the map's channels (w and per-pixel parameters) in float64 while built, float32 when written
    require_memory(h * w * 8 * 16, "--resolution", f"a {h}×{w} map", getattr(args, "max_memory", None))
    if not args.mesh:
        check_outputs([Output(args.output, "--output", (".exr",))], inputs=[*args.photo, args.hiraji, args.hamon])
    if args.default and (args.hiraji or args.hamon or args.photo):
        raise InputError("--default writes the built-in map; --hiraji, --hamon and PHOTO apply to a photo's map",
                         field="--default")
    if args.mesh:
        return _map_on_mesh(args)
    if len(args.photo) > 1:
        raise InputError(f"{len(args.photo)} photos: several photos need --mesh (the blade they are registered on)",
                         field="photo")
    args.photo = args.photo[0] if args.photo else None
    if args.default:
        m = default_map(tuple(args.resolution))
    else:
        if not args.photo:
            raise InputError("give a PHOTO or --default", field="photo")
        y = read_photo(args.photo)
        m = map_from_photo(
            y, resolution=tuple(args.resolution), crop=args.crop, dark=args.dark, bright=args.bright,
            hiraji=load_region_parameters(args.hiraji, "hiraji") if args.hiraji else None,
            hamon=load_region_parameters(args.hamon, "hamon") if args.hamon else None,
            flip_v=args.flip_v, expected_aspect=args.aspect, path=args.photo)
    m.write(args.output)
    print(f"wrote {args.output}: {m.shape[0]}×{m.shape[1]}, mean w = {m.w.mean():.3f}", file=sys.stderr)
    return 0


def _per_photo(values, n: int, field: str):
    from jkatana.errors import InputError

    if values is None:
        return None
    if len(values) == 1:
        return list(values) * n
    if len(values) != n:
        raise InputError(f"give one value or one per photo ({n}), got {len(values)}", field=field)
    return list(values)


def _map_on_mesh(args: argparse.Namespace) -> int:
    """``jkatana map PHOTO... --mesh BLADE.ply``: register each photo on the mesh, blend, write the map,
    its confidence, a preview and a report; print a one-line summary with the registration residual."""
    import json
    from pathlib import Path

    from jkatana.errors import InputError
    from jkatana.io.atomic import write_text
    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs
    from jkatana.maps.mosaic import build_map, preview_png, write_confidence
    from jkatana.maps.photo import load_region_parameters, read_photo
    from jkatana.maps.surface import blade_surface
    from jkatana.shape.mesh import read_mesh

    if args.default or args.crop or args.flip_v or args.aspect:
        raise InputError("--mesh registers the photos on the blade; --default, --crop, --flip-v and --aspect "
                         "are for a single straightened photo", field="--mesh")
    if not args.photo:
        raise InputError("give one or more PHOTOs with --mesh", field="photo")
    n = len(args.photo)
    out = Path(args.output)
    stem = out.with_suffix("")
    conf_path = Path(args.confidence) if args.confidence else stem.with_name(stem.name + "_confidence.exr")
    prev_path = Path(args.preview) if args.preview else stem.with_name(stem.name + "_preview.png")
    rep_path = Path(args.report) if args.report else stem.with_name(stem.name + "_registration.json")
    flats = _per_photo(args.flat, n, "--flat")
    check_outputs([Output(out, "--output", (".exr",)), Output(conf_path, "--confidence", (".exr",)),
                   Output(prev_path, "--preview", (".png",)), Output(rep_path, "--report", (".json",))],
                  inputs=[*args.photo, args.mesh, args.hiraji, args.hamon, args.points, *(flats or [])])
    focal_mm = _per_photo(args.focal_mm, n, "--focal-mm")
    for f in focal_mm or []:
        number(f, "--focal-mm", lo=0, lo_open=True, hi=1e4)
    if focal_mm and args.sensor_mm is None:
        raise InputError("--focal-mm needs --sensor-mm (the sensor's width) to become pixels", field="--sensor-mm")
    number(args.sensor_mm, "--sensor-mm", lo=0, lo_open=True, hi=1e3)
    sides = [None if s == "auto" else s for s in (_per_photo(args.side, n, "--side") or [None] * n)]
    points = None
    if args.points:
        from jkatana.io.jsonfile import read_json

        points = read_json(args.points)
        if not isinstance(points, dict):
            raise InputError("must be an object {photo name: {side, points}}", path=args.points)
        names = {Path(p).name for p in args.photo}
        for k, v in points.items():
            if k not in names:
                raise InputError(f"names {k!r}, which is not one of the photos", path=args.points, field=k)
            pts = v.get("points") if isinstance(v, dict) else None
            if (not isinstance(pts, list) or len(pts) < 3
                    or not all(isinstance(q, list) and len(q) == 4 for q in pts)):
                raise InputError(f"{k}: need at least 3 points [x, y, u, v]", path=args.points, field="points")
            if v.get("side", "omote") not in ("omote", "ura"):
                raise InputError(f"{k}: side must be omote or ura", path=args.points, field="side")
    surface = blade_surface(read_mesh(args.mesh), tuple(args.resolution), path=args.mesh)
    photos = [(p, read_photo(p)) for p in args.photo]
    flat_img = [read_photo(f) for f in flats] if flats else None
    focal_px = [fm / args.sensor_mm * y.shape[1] for fm, (_, y) in zip(focal_mm, photos)] if focal_mm else None
    res = build_map(photos, surface, flats=flat_img, focal_px=focal_px, sides=sides, points=points,
                    dark=args.dark, bright=args.bright,
                    hiraji=load_region_parameters(args.hiraji, "hiraji") if args.hiraji else None,
                    hamon=load_region_parameters(args.hamon, "hamon") if args.hamon else None)
    res.map.write(out)
    write_confidence(res, conf_path)
    preview_png(res, photos, surface, prev_path)
    write_text(rep_path, json.dumps({**res.report, "summary": res.summary, "map": str(out),
                                     "confidence": str(conf_path), "preview": str(prev_path)}, indent=1))
    print(res.summary, file=sys.stderr)
    print(f"wrote {out}, {conf_path}, {prev_path}, {rep_path}", file=sys.stderr)
    return 0

"""CLI of the maps stage: ``jkatana map PHOTO -o MAP.exr``."""

from __future__ import annotations

import argparse
import sys

MAP_HELP = "Reflectance map (w and per-pixel parameters, EXR) from a diffuse-lit photo of the blade."


def map_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("photo", nargs="?", help="photo under diffuse light (.exr, 16-bit .png/.tif, or camera RAW via rawpy); "
                   "omit with --default")
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
    check_outputs([Output(args.output, "--output", (".exr",))], inputs=[args.photo, args.hiraji, args.hamon])
    if args.default and (args.hiraji or args.hamon or args.photo):
        raise InputError("--default writes the built-in map; --hiraji, --hamon and PHOTO apply to a photo's map",
                         field="--default")
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

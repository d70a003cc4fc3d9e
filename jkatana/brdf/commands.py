"""``jkatana brdf slice``: a measured BRDF sliced in a goniometer protocol into a table ``jkatana fit`` reads."""

from __future__ import annotations

import argparse

BRDF_HELP = "Measured BRDFs (MERL .binary, RGL .bsdf, BRDF table .csv): slice into a measurement table."


def brdf_add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="brdf_command", metavar="ACTION", required=True)
    p = sub.add_parser("slice", help="slice a measured BRDF in a protocol (in-plane -> measurement table, "
                                     "out-of-plane -> BRDF table)")
    p.add_argument("brdf", help="MERL .binary, RGL .bsdf or BRDF table .csv")
    p.add_argument("-o", "--output", required=True, help="table to write (.csv; .parquet for a measurement table)")
    p.add_argument("--channel", default="green", help="channel: red/green/blue (MERL, RGB .bsdf) or e.g. 550nm")
    p.add_argument("--incidences", default="15,25,35,45,55,65", help="incidence angles (deg), comma-separated")
    p.add_argument("--receive-min", type=float, default=10.0, help="smallest receiving angle (deg)")
    p.add_argument("--receive-max", type=float, default=80.0, help="largest receiving angle (deg)")
    p.add_argument("--dense-step", type=float, default=0.2, help="receiving step near the peak (deg)")
    p.add_argument("--dense-halfwidth", type=float, default=20.0, help="dense window half-width (deg)")
    p.add_argument("--sparse-step", type=float, default=2.0, help="receiving step elsewhere (deg)")
    p.add_argument("--source-radius-deg", type=float, default=0.0,
                   help="the instrument: angular radius of the source seen from the sample (deg), stored beside "
                        "the table for `jkatana fit`")
    p.add_argument("--aperture-radius-deg", type=float, default=0.0,
                   help="the instrument: angular radius of the detector aperture seen from the sample (deg)")
    p.add_argument("--azimuth", default="0", help="receiver azimuths out of the plane (deg), comma-separated")
    p.add_argument("--relative-noise", type=float, default=0.05, help="sigma: relative part")
    p.add_argument("--floor-fraction", type=float, default=1e-3, help="sigma: absolute part as a fraction of peak")
    p.add_argument("--seed", type=int, default=None, help="draw noise of that sigma with this seed (default: none)")
    p.add_argument("--region", default="hiraji", help="region name of the measurement table's rows")
    p.add_argument("--method", choices=["linear", "nearest"], default="linear",
                   help="MERL lookup: trilinear or the reference reader's nearest-lower sample")


def _floats(text, field):
    from jkatana.errors import InputError

    try:
        return tuple(float(v) for v in str(text).split(",") if v.strip())
    except ValueError:
        raise InputError(f"expected comma-separated numbers, got {text!r}", field=field) from None


def brdf_run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from jkatana.brdf.merl import MerlBRDF
    from jkatana.brdf.slicing import load_brdf, slice_brdf, to_measurement_table
    from jkatana.brdf.table import BRDFTable, write_brdf_table
    from jkatana.errors import InputError
    from jkatana.measure.protocol import Instrument, Protocol, instrument_angle, write_instrument
    from jkatana.measure.table import write_table

    from jkatana.io.outputs import Output, check_outputs

    check_outputs([Output(args.output, "--output", (".csv", ".parquet"))], inputs=[args.brdf])
    from jkatana.io.limits import number

    number(args.seed, "--seed", lo=0, hi=2 ** 32 - 1, integer=True)
    inst = Instrument(*(instrument_angle(getattr(args, f), f.replace("_", "-"))
                        for f in ("source_radius_deg", "aperture_radius_deg")))
    src = load_brdf(args.brdf)
    az = _floats(args.azimuth, "azimuth")
    if isinstance(src, BRDFTable):
        table = src.select(args.channel) if args.channel in src.channels else src
    else:
        proto = Protocol(incidences_deg=_floats(args.incidences, "incidences"), receive_min_deg=args.receive_min,
                         receive_max_deg=args.receive_max, dense_step_deg=args.dense_step,
                         dense_halfwidth_deg=args.dense_halfwidth, sparse_step_deg=args.sparse_step,
                         source_radius_deg=args.source_radius_deg, aperture_radius_deg=args.aperture_radius_deg)
        for name in ("relative_noise", "floor_fraction"):
            v = getattr(args, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"must be finite and >= 0, got {v}", field=name.replace("_", "-"))
        kw = dict(method=args.method) if isinstance(src, MerlBRDF) else {}
        table = slice_brdf(src, proto, channel=args.channel, azimuths_deg=az,
                           noise=(args.relative_noise, args.floor_fraction), seed=args.seed, **kw)
    out = Path(args.output)
    if np.all(np.isclose(table.azimuth_deg, 0.0)) and out.suffix.lower() in (".csv", ".parquet") and not (
            out.suffix.lower() == ".csv" and len(az) > 1):
        write_table(to_measurement_table(table, region=args.region, channel=args.channel
                                         if args.channel in table.channels else None), out)
        kind = "measurement table"
    else:
        if out.suffix.lower() != ".csv":
            raise InputError("an out-of-plane slice is a BRDF table: use a .csv output", path=out)
        write_brdf_table(table, out)
        kind = "BRDF table"
    write_instrument(out, inst)
    print(f"{args.brdf}: {len(table)} rows ({kind}, channel {args.channel}) -> {out}"
          + (f" (instrument: source {inst.source_radius_deg:g} deg, aperture {inst.aperture_radius_deg:g} deg)"
             if inst else ""))
    return 0

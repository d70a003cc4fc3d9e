"""``jkatana simulate`` and ``jkatana measure``: the goniometer stage's commands."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

SIMULATE_HELP = ("Simulate a goniometer campaign: write DNG captures, manifest.csv and truth.csv "
                 "(paper protocol by default; noise, quantisation, jitter, tilt, stray light only when asked).")
MEASURE_HELP = "Ingest a capture manifest (RAW/DNG, 16-bit TIFF, EXR) into a measurement table (CSV/Parquet)."


def _progress(total: int, desc: str, disable: bool, unit: str = "capture"):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=disable, file=sys.stderr)


def _kv(text: str) -> tuple[str, dict]:
    """``hiraji:chi=79000,mu=0.05`` → ("hiraji", {"chi": 79000.0, "mu": 0.05})."""
    from jkatana.errors import InputError

    try:
        region, rest = text.split(":", 1)
        params = {k.strip(): float(v) for k, v in (item.split("=", 1) for item in rest.split(",") if item)}
    except ValueError:
        raise InputError(f"expected REGION:name=value,..., got {text!r}", field="--params") from None
    for k, v in params.items():
        if not math.isfinite(v):
            raise InputError(f"{region.strip()}:{k} must be a finite number, got {v!r}", field="--params")
    return region.strip(), params


def _check_simulate(args) -> None:
    """Every number of ``simulate`` in range, and the frames' memory within the budget."""
    from jkatana.io.limits import number, numbers, require_memory

    numbers(args.incidences, "--incidences", lo=0, hi=89.999)
    number(args.dense_step, "--dense-step", lo=0.001, hi=90)
    number(args.sparse_step, "--sparse-step", lo=0.001, hi=90)
    w, h = numbers(args.size, "--size", lo=24, hi=2 ** 20, integer=True)
    number(args.full_well, "--full-well", lo=0, lo_open=True)
    number(args.read_noise, "--read-noise", lo=0)
    number(args.exposure, "--exposure", lo=0, lo_open=True, hi=3600)
    number(args.fill, "--fill", lo=0, lo_open=True, hi=4)
    number(args.tilt, "--tilt", lo=-89.999, hi=89.999)
    number(args.jitter, "--jitter", lo=0, hi=90)
    number(args.stray, "--stray", lo=0)
    number(args.seed, "--seed", lo=0, hi=2 ** 32 - 1, integer=True)
    # a frame lives as float64 model, black and DN planes plus the uint16 mosaic and its DNG buffer
    require_memory(w * h * (4 * 8 + 3 * 2), "--size", f"a {w}×{h} frame", getattr(args, "max_memory", None))


def simulate_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--incidences", type=float, nargs="+", default=None,
                   help="incidence settings θi in degrees (default: the paper's 15 25 35 45 55 65)")
    p.add_argument("--dense-step", type=float, default=0.2, help="θr step within ±20° of the peak (deg)")
    p.add_argument("--sparse-step", type=float, default=2.0, help="θr step elsewhere (deg)")
    p.add_argument("--regions", nargs="+", default=["hiraji", "hamon"], choices=["hiraji", "hamon"])
    p.add_argument("--params", action="append", default=[], metavar="REGION:k=v,...",
                   help="model parameters, e.g. hiraji:chi=79000,mu=0.05 (default: the paper's fit)")
    p.add_argument("--optical-constants", default="Fe-Johnson", help="Fe-Johnson, Fe-Querry or a YAML path")
    p.add_argument("--light", default="D65", help="CIE illuminant name or CCT (e.g. 5000K)")
    p.add_argument("--camera", default="Nikon 5100 (NPL)", help="colour-science camera sensitivity name")
    p.add_argument("--size", type=int, nargs=2, default=(64, 64), metavar=("W", "H"), help="frame size")
    p.add_argument("--bits", type=int, default=16, choices=[12, 14, 16],
                   help="RAW bit depth (14: the EOS 40D's quantisation and clipping)")
    p.add_argument("--full-well", type=float, default=None, help="electrons at full scale (photon noise)")
    p.add_argument("--read-noise", type=float, default=0.0, help="read noise in DN")
    p.add_argument("--exposure", type=float, default=None, help="force one exposure (s); default auto")
    p.add_argument("--fill", type=float, default=0.5, help="auto exposure: fraction of full scale at the peak")
    p.add_argument("--tilt", type=float, default=0.0, help="sample tilt in degrees (positive towards the light)")
    p.add_argument("--jitter", type=float, default=0.0, help="angle jitter, standard deviation in degrees")
    p.add_argument("--stray", type=float, default=0.0, help="stray-light floor in camera units")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="keep DNG files already written")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def simulate_run(args: argparse.Namespace) -> int:
    from jkatana.measure.goniometer import Sensor, simulate_campaign
    from jkatana.measure.protocol import Protocol

    from jkatana.io.outputs import Output, check_outputs

    _check_simulate(args)
    check_outputs([Output(args.output, "--output", folder=True)])
    protocol = Protocol(**({"incidences_deg": tuple(args.incidences)} if args.incidences else {}),
                        dense_step_deg=args.dense_step, sparse_step_deg=args.sparse_step)
    params = dict(_kv(t) for t in args.params)
    sensor = Sensor(width=args.size[0], height=args.size[1], bits=args.bits, full_well_e=args.full_well,
                    read_noise_dn=args.read_noise)
    n = len(protocol)
    with _progress(n, "simulate", args.quiet) as bar:
        result = simulate_campaign(args.output, protocol, regions=args.regions, params=params,
                                   optical_constants=args.optical_constants, light=args.light,
                                   camera=args.camera, sensor=sensor, exposure_s=args.exposure, fill=args.fill,
                                   tilt_deg=args.tilt, stray_floor=args.stray, angle_jitter_deg=args.jitter,
                                   seed=args.seed, resume=args.resume, progress=bar.update)
    print(f"wrote {result['captures']} captures ({result['rows']} rows) to {args.output}; "
          f"manifest {result['manifest']}", file=sys.stderr)
    return 0


def measure_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("manifest", type=Path, help="capture manifest (CSV or TOML)")
    p.add_argument("-o", "--output", required=True, type=Path, help="measurement table (.csv or .parquet)")
    p.add_argument("-j", "--workers", type=int, default=0,
                   help="decoding processes (default 0 = auto: 2 when the captures are large, else 1)")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG",
                   help="also draw the table (value vs θr per incidence, log scale) to this PNG")
    p.add_argument("--overlay", type=Path, default=None, metavar="TABLE",
                   help="with --plot: draw this table (e.g. a simulation's truth.csv) as lines, "
                        "and write PNG's '-residuals' companion")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def measure_run(args: argparse.Namespace) -> int:
    import numpy as np

    from jkatana.measure.ingest import measure_to_file
    from jkatana.measure.manifest import read_manifest

    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    number(args.workers, "--workers", lo=0, hi=256, integer=True)
    if args.overlay is not None and args.plot is None:
        from jkatana.errors import InputError
        raise InputError("--overlay draws on the --plot; give --plot too", field="--overlay")
    outputs = [Output(args.output, "--output", (".csv", ".parquet"))]
    if args.plot is not None:
        outputs.append(Output(args.plot, "--plot", (".png",)))
        if args.overlay is not None:
            outputs.append(Output(args.plot.with_name(args.plot.stem + "-residuals.png"), "--plot"))
    check_outputs(outputs, inputs=[args.manifest, args.overlay])
    manifest = read_manifest(args.manifest)
    check_outputs(outputs, inputs=[e.file for e in manifest.entries] + [e.dark for e in manifest.entries])
    with _progress(len(manifest), "measure", args.quiet, unit="row") as bar:
        table = measure_to_file(manifest, args.output, workers=args.workers or None,
                                progress=bar.update)
    if args.plot is not None:
        from jkatana.measure.plot import plot_residuals, plot_table
        from jkatana.measure.table import read_table

        overlay = read_table(args.overlay) if args.overlay is not None else None
        plot_table(table, args.plot, overlay=overlay, title=str(args.manifest))
        if overlay is not None:
            plot_residuals(table, overlay, args.plot.with_name(args.plot.stem + "-residuals.png"))
    sat = int(np.count_nonzero(table.n_saturated))
    print(f"wrote {len(table)} rows to {args.output}"
          + (f"; {sat} rows had saturated photosites (excluded from their means, see n_saturated)" if sat else ""),
          file=sys.stderr)
    return 0

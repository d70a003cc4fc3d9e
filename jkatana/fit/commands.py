"""``jkatana fit`` and ``jkatana report``: thin CLI wrappers around :mod:`jkatana.fit`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

FIT_HELP = "Fit eq. (3)/(4) to a measurement table: values, Laplace and emcee intervals, quality per incidence."
REPORT_HELP = "Write a Markdown report with plots (fit per incidence, residuals, quality, corner) from a parameter file."


def fit_add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("table", help="measurement table (CSV or Parquet, jkatana.measure.table)")
    parser.add_argument("-o", "--output", required=True, help="parameter file to write (JSON)")
    parser.add_argument("--region", default=None, help="region to fit (default: the table's only region)")
    parser.add_argument("--model", choices=["hiraji", "hamon"], default=None,
                        help="model (default: the region's own: hiraji → eq. 3, hamon → eq. 4)")
    parser.add_argument("--solver", choices=["lm", "dogleg", "gn", "jaxopt"], default="lm")
    parser.add_argument("--tilt", action="store_true", help="free sample tilt (degrees, towards the light)")
    parser.add_argument("--floor", action="store_true", help="free constant floor (camera units)")
    parser.add_argument("--emcee", action="store_true", help="also sample the posterior with emcee")
    parser.add_argument("--optical-constants", default="Fe-Johnson", help="Fe-Johnson, Fe-Querry or a YAML path")
    parser.add_argument("--camera", default="Nikon 5100 (NPL)", help="colour-science camera name")
    parser.add_argument("--light", default="D65", help="illuminant name or CCT")
    parser.add_argument("--multistart", action="store_true", help="also try a coarse-grid start")
    parser.add_argument("--seed", type=int, default=0, help="emcee seed")


def _x64():
    import jax

    jax.config.update("jax_enable_x64", True)  # fits are float64 (DESIGN: numerical core)


def _check_fit_data(data, args) -> None:
    """Data a least-squares fit can use: more usable points than free parameters, and values whose
    squares (the χ² sums) stay finite in float64 (|value| below 1e150)."""
    import numpy as np

    from jkatana.errors import InputError

    n_free = 2 + int(args.tilt) + int(args.floor)
    n = int(np.count_nonzero(data.usable))
    if n <= n_free:
        raise InputError(f"region {data.region!r} has {n} usable row(s); a fit of {n_free} free parameters "
                         f"needs at least {n_free + 1}", path=args.table, field="value")
    for name, col in (("value", data.value), ("sigma", data.sigma)):
        if col is None:
            continue
        big = np.abs(col[data.usable]) > 1e150
        if big.any():
            raise InputError(f"{int(big.sum())} value(s) beyond ±1e150: their squares overflow float64 in the "
                             "fit's sums (rescale the table, e.g. the manifest's gain)", path=args.table, field=name)


def fit_run(args: argparse.Namespace) -> int:
    _x64()
    from tqdm import tqdm

    from jkatana.errors import InputError
    from jkatana.fit.params import write_params
    from jkatana.fit.posterior import sample
    from jkatana.fit.region import FitData, Setup, fit_region
    from jkatana.measure.table import read_table

    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    number(args.seed, "--seed", lo=0, hi=2 ** 32 - 1, integer=True)
    check_outputs([Output(args.output, "--output", (".json",))], inputs=[args.table])
    table = read_table(args.table)
    data = FitData.from_table(table, args.region, source=args.table)
    _check_fit_data(data, args)
    setup = Setup(optical_constants=args.optical_constants, camera=args.camera, light=args.light)
    with tqdm(total=2 + int(args.emcee), desc=f"fit {data.region}", file=sys.stderr) as bar:
        bar.set_postfix_str("least squares + per-incidence refits")
        fit = fit_region(data, model=args.model, setup=setup, tilt=args.tilt, floor=args.floor,
                         solver=args.solver, multistart=args.multistart)
        bar.update(2)
        if args.emcee:
            bar.set_postfix_str("emcee")
            fit.emcee = sample(fit, seed=args.seed)
            bar.update(1)
    try:
        rel = str(Path(args.table).resolve())
    except OSError:
        raise InputError("cannot resolve", path=args.table) from None
    write_params(fit, args.output, table_path=rel)
    status = "converged" if fit.converged else "NOT CONVERGED: " + "; ".join(fit.reasons)
    vals = ", ".join(f"{k}={v:.6g} [{fit.laplace['ci95'][k][0]:.6g}, {fit.laplace['ci95'][k][1]:.6g}]"
                     for k, v in fit.values.items())
    print(f"{data.region}: {vals}; chi2/dof={fit.diagnostics['chi2_dof']:.3f}; {status} -> {args.output}")
    return 0 if fit.converged else 1


def report_add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("params", help="parameter file written by `jkatana fit`")
    parser.add_argument("-o", "--output", required=True, help="directory for report.md and the PNGs")
    parser.add_argument("--table", default=None, help="measurement table (default: the one named in the file)")


def _check_report_params(path) -> None:
    """The parts of a parameter file the report draws (fit's diagnostics and Laplace intervals)."""
    from jkatana.errors import InputError
    from jkatana.fit.params import read_params

    d = read_params(path).raw
    for key in ("diagnostics", "laplace"):
        if not isinstance(d.get(key), dict):
            raise InputError("missing or not an object (the report draws it; write the file with "
                             "`jkatana fit`)", path=path, field=key)
    if not isinstance(d["laplace"].get("ci95", {}), dict):
        raise InputError("not an object", path=path, field="laplace.ci95")


def report_run(args: argparse.Namespace) -> int:
    _x64()
    from jkatana.fit.report import write_report
    from jkatana.io.outputs import Output, check_outputs

    check_outputs([Output(args.output, "--output", folder=True)])
    out = Path(args.output)
    for src in (args.params, args.table):
        if src is not None and out.exists() and Path(src).resolve().parent == out.resolve() \
                and Path(src).name in ("report.md", "params.json"):
            from jkatana.errors import InputError
            raise InputError("the report would overwrite its own input", path=src, field="--output")
    _check_report_params(args.params)
    md = write_report(args.params, args.output, table=args.table)
    print(md)
    return 0

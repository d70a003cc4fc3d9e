"""``jkatana fit`` and ``jkatana report``: thin CLI wrappers around :mod:`jkatana.fit`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

FIT_HELP = ("Fit a lobe (the paper's eq. 3/4, Beckmann, GGX, GTR, two-lobe) to a measurement or BRDF table: values, "
            "Laplace, robust and optional bootstrap/emcee intervals, misfit flag, quality per incidence.")
REPORT_HELP = "Write a Markdown report with plots (fit per incidence, residuals, quality, corner) from a parameter file."


def _models():
    from jkatana.fit._model import MODELS

    return list(MODELS)


def fit_add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("table", help="measurement table (CSV/Parquet, jkatana.measure.table) or a BRDF table "
                                      "(CSV, jkatana.brdf.table)")
    parser.add_argument("-o", "--output", required=True, help="parameter file to write (JSON)")
    parser.add_argument("--region", default=None, help="region to fit (default: the table's only region)")
    parser.add_argument("--model", choices=_models(), default=None,
                        help="model (default: the region's own: hiraji -> eq. 3, hamon -> eq. 4)")
    parser.add_argument("--channel", default=None, help="channel of a BRDF table (default: its only channel)")
    parser.add_argument("--solver", choices=["lm", "dogleg", "gn", "jaxopt"], default="lm")
    parser.add_argument("--tilt", action="store_true", help="free sample tilt (degrees, towards the light)")
    parser.add_argument("--floor", action="store_true", help="free constant floor (camera units)")
    parser.add_argument("--noise", choices=["auto", "given", "model"], default="auto",
                        help="per-row sigma as given (auto: when every row has one) or a fitted noise model")
    parser.add_argument("--loss", choices=["squared", "huber", "cauchy"], default="squared",
                        help="robust loss for outlying captures (IRLS)")
    parser.add_argument("--source-radius-deg", type=float, default=None,
                        help="angular radius of the source seen from the sample (instrument response; default: "
                             "the table's instrument file TABLE.instrument.json, else 0)")
    parser.add_argument("--aperture-radius-deg", type=float, default=None,
                        help="angular radius of the detector aperture seen from the sample (instrument response; "
                             "default: the table's instrument file, else 0)")
    parser.add_argument("--instrument-points", type=int, default=None,
                        help="quadrature points per disk of the instrument response (default: the table's, else 12)")
    parser.add_argument("--bootstrap", type=int, default=0, help="cluster-bootstrap replicates over incidences")
    parser.add_argument("--emcee", action="store_true", help="also sample the posterior with emcee")
    parser.add_argument("--optical-constants", default="Fe-Johnson",
                        help="a shipped table (Fe-Johnson, Fe-Querry, Cr-Johnson, Ni-Johnson, SS-Karlsson-austenitic, "
                             "...) or a refractiveindex.info YAML path")
    parser.add_argument("--camera", default="Nikon 5100 (NPL)",
                        help="colour-science camera name (green), 'NAME:red|green|blue', 'band:LO-HI' (nm), "
                             "or a CSV/JSON sensitivity file")
    parser.add_argument("--light", default="D65", help="illuminant name or CCT")
    parser.add_argument("--multistart", action="store_true", help="also try a coarse-grid start")
    parser.add_argument("--seed", type=int, default=0, help="emcee / bootstrap seed")


def _x64():
    """float64 fits (DESIGN: numerical core), XLA on one thread and JAX's persistent compilation cache.

    A fit's programs are small: XLA runs them on a one-thread pool
    (:func:`jkatana.runtime.xla_threads`; ``$JKATANA_XLA_THREADS``, default 1,
    ``all`` for JAX's default of one per core), which lowers their CPU time and
    keeps their wall time steady on a shared machine.

    The cache (``$JKATANA_CACHE``, else ``~/.cache/jkatana``, folder ``jax``)
    keeps the compiled programs between runs, so the second ``jkatana fit`` of a
    table of the same shape and model pays tracing, not XLA compilation. Every
    program is kept, however quick to compile: a fit runs about a hundred small
    ones (eager array operations, per-incidence refits, intervals) whose
    compilation together costs as much as the solver's; the cache of one
    model and table shape is about 1 MB.
    Set ``JKATANA_NO_JAX_CACHE=1`` to switch it off.
    """
    import os

    import jax

    from jkatana.runtime import ENV_VAR, compile_cache, xla_threads

    xla_threads(os.environ.get(ENV_VAR, "1"))
    jax.config.update("jax_enable_x64", True)
    compile_cache()


def instrument_from_args(args, table=None):
    """The instrument of a fit: the table's (``TABLE.instrument.json``, written by ``jkatana measure`` from the
    manifest and by ``jkatana brdf slice`` from its protocol), each value overridden by its CLI flag; an
    override of a value the table gives prints a note. Returns the fit's ``instrument`` argument."""
    from jkatana.errors import InputError
    from jkatana.measure.protocol import Instrument, instrument_angle, read_instrument

    stored = read_instrument(table) if table is not None else None
    base = stored or Instrument()
    flags = {"source_radius_deg": args.source_radius_deg, "aperture_radius_deg": args.aperture_radius_deg,
             "points": args.instrument_points}
    values = {}
    for name, flag in flags.items():
        cli = "--" + name.replace("_", "-").replace("points", "instrument-points")
        if flag is None:
            values[name] = getattr(base, name)
            continue
        if name == "points":
            if flag < 1:
                raise InputError(f"must be >= 1, got {flag}", field="instrument-points")
        else:
            flag = instrument_angle(flag, cli.lstrip("-"))
        if stored is not None and flag != getattr(stored, name):
            print(f"note: {cli} {flag:g} overrides the table's {getattr(stored, name):g} "
                  f"({table} instrument)", file=sys.stderr)
        values[name] = flag
    return Instrument(values["source_radius_deg"], values["aperture_radius_deg"], int(values["points"])).radians()


def summary(fit, output=None) -> str:
    """The lines ``jkatana fit`` prints: model, χ²/dof and misfit, every method's 95 % intervals."""
    f = lambda x: f"{x:.6g}"  # noqa: E731
    head = f"{fit.region} (model {fit.spec.model}): chi2/dof={fit.diagnostics['chi2_dof']:.3f}"
    if fit.misfit and fit.misfit["flag"]:
        head += " -- " + fit.misfit["note"]
    lines = [head]
    methods = [("Laplace", fit.laplace), ("robust", fit.robust), ("bootstrap", fit.bootstrap), ("emcee", fit.emcee)]
    for name, v in fit.values.items():
        cells = [f"  {name} = {f(v)}"]
        for label, m in methods:
            ci = ((m or {}).get("ci95") or {}).get(name)
            if ci is not None:
                cells.append(f"{label} [{f(ci[0])}, {f(ci[1])}]")
        lines.append(" | ".join(cells))
    status = "converged" if fit.converged else "NOT CONVERGED: " + "; ".join(fit.reasons)
    lines.append(status + (f" -> {output}" if output else ""))
    return "\n".join(lines)


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
    from jkatana.fit.region import Setup, fit_region, load_fit_data

    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    number(args.seed, "--seed", lo=0, hi=2 ** 32 - 1, integer=True)
    # 0 = none; 10 000 replicates put a 95 % interval's ends within a few per cent (Efron & Tibshirani 1993,
    # ch. 19, ask 1000-2000), and each is a refit: more is work without a bound
    number(args.bootstrap, "--bootstrap", lo=0, hi=10000, integer=True)
    check_outputs([Output(args.output, "--output", (".json",))], inputs=[args.table])
    data = load_fit_data(args.table, args.region, args.channel)
    _check_fit_data(data, args)
    setup = Setup(optical_constants=args.optical_constants, camera=args.camera, light=args.light)
    setup.weights()  # bad camera / light names fail here, before any compilation
    with tqdm(total=2 + int(args.emcee), desc=f"fit {data.region}", file=sys.stderr) as bar:
        bar.set_postfix_str("least squares + per-incidence refits")
        fit = fit_region(data, model=args.model, setup=setup, tilt=args.tilt, floor=args.floor,
                         solver=args.solver, multistart=args.multistart, noise=args.noise, loss=args.loss,
                         instrument=instrument_from_args(args, args.table), bootstrap=args.bootstrap, seed=args.seed)
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
    print(summary(fit, args.output))
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


COMPARE_HELP = ("Compare every lobe on one table: per-incidence chi2/dof, AIC/BIC and leave-one-incidence-out "
                "prediction error, as a table and a plot.")


def compare_add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("table", help="measurement table or BRDF table (as for `jkatana fit`)")
    parser.add_argument("-o", "--output", required=True, help="directory for compare.md, compare.json, compare.png")
    parser.add_argument("--region", default=None, help="region (default: the table's only region)")
    parser.add_argument("--channel", default=None, help="channel of a BRDF table")
    parser.add_argument("--models", default=",".join(_models()),
                        help=f"comma-separated models (default: all of {','.join(_models())})")
    parser.add_argument("--noise", choices=["auto", "given", "model"], default="auto")
    parser.add_argument("--optical-constants", default="Fe-Johnson")
    parser.add_argument("--camera", default="Nikon 5100 (NPL)")
    parser.add_argument("--light", default="D65")


def compare_run(args: argparse.Namespace) -> int:
    _x64()
    from jkatana.errors import InputError
    from jkatana.fit.compare import compare_models, write_comparison
    from jkatana.fit.region import Setup, load_fit_data

    from jkatana.io.outputs import Output, check_outputs

    check_outputs([Output(args.output, "--output", folder=True)], inputs=[args.table])
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    bad = [m for m in models if m not in _models()]
    if bad or not models:
        raise InputError(f"unknown models {bad} (known: {_models()})", field="models")
    data = load_fit_data(args.table, args.region, args.channel)
    setup = Setup(optical_constants=args.optical_constants, camera=args.camera, light=args.light)
    setup.weights()
    result = compare_models(data, models, setup=setup, noise=args.noise)
    md = write_comparison(result, args.output)
    for r in result["models"]:
        print(f"{r['model']:>9}: chi2/dof={r['chi2_dof']:.4g} dAIC={r['daic']:.4g} dBIC={r['dbic']:.4g} "
              f"LOIO={r['loio_mean']:.4g} converged={r['converged']}")
    print(f"best: AIC {result['best_aic']}, BIC {result['best_bic']}, LOIO {result['best_loio']} -> {md}")
    return 0

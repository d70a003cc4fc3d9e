"""jkatana's benchmark suite: what accuracy costs in time.

Each ``benchmarks/bench_*.py`` module defines ``run(quick: bool) -> list[dict]``
returning records made with :func:`benchmarks._harness.record`. The runner
(``python -m benchmarks`` or ``jkatana bench``) runs every module in its own
subprocess, so peak memory and JIT caches are per benchmark, enforces a time
budget per module, and writes one JSON results file with the machine's facts.
``--report DIR`` renders ``report.md``, ``headline.md`` and PNG plots from it
(:mod:`benchmarks.report`).

## Modes and budgets

``--quick`` (CI smoke: small sizes, a 900 s budget for the whole suite) and
``--full`` (the default; a 1680 s budget, so the whole suite fits in 30 minutes
on 2 cores). The runner gives each module a
wall-clock budget (``--budget-total`` shared among the modules still to run;
time a module leaves unused rolls over to the next) and kills a module that
overruns it; the records it had already made survive (``record`` appends each
row to a side file) and are marked ``"partial": true``. A module may read its
own budget with :func:`benchmarks._harness.budget_s` to size its work.
A failing module is reported (status, stderr tail) and never stops the others.

## Record convention for accuracy–time studies

Any record can opt in to a *study* — a set of variants of one computation
whose error against one reference and whose time are both measured — by
passing these extra keyword arguments to ``record(...)``:

| key | type | meaning |
| --- | --- | --- |
| ``study`` | str | the study's name, e.g. ``"spectral sampling"``; records from several modules may share one |
| ``variant`` | str | this point's label, e.g. ``"16 bands"`` |
| ``error_metric`` | str | key of ``error`` plotted on the y axis, e.g. ``"dE2000_mean"`` |
| ``time_s`` | dict | from :func:`~benchmarks._harness.timeit`; ``time_s["median"]`` is the x axis, ``min``/``max`` the error bar |
| ``error`` | dict | every error metric measured, in the unit a user cares about (see below) |
| ``reference`` | str | what the error is measured against |
| ``is_reference`` | bool, optional | this variant *is* the reference (its error is 0 by construction or its own self-check) |
| ``items`` | int, optional | work items timed per call (pixels, points): the report adds time per item |
| ``tolerance`` | float, optional | error below which the variant is "as good as the reference" (e.g. ΔE2000 1.0, a just-noticeable difference); drawn on the plot and used for the headline |
| ``headline`` | bool, optional | force this record into the headline table |
| ``note`` | str, optional | one line shown in the study's table |
| ``series`` | str, optional | which method/renderer family this point belongs to (default: ``case["renderer"]`` if present); with ≥ 2 series of ≥ 2 points, the report gives their time ratio *at equal error* (log–log interpolation along each series' measured Pareto front, never extrapolated) |

Error units: ``dE2000_mean`` / ``dE2000_p95`` (CIE ΔE 2000 after the same
display transform, :func:`jkatana.spectral.delta_e_display`) for images
and colours; ``rel_error`` (max or median relative error) for fitted
parameters; ``coverage`` (fraction of true values inside the intervals) and
``width`` for intervals; ``max_abs`` for a function like Fresnel's F.
Non-finite errors (an overflow in float16, a diverged fit) are kept: the
report lists them in the table and leaves them out of the plot, saying so.

A *comparison* measured directly as one number is a record with ``ratio``
(float) and ``ratio_label`` (str); the report lists these, and the
equal-error ratios it derives from ``series``, in a section of their own
(e.g. Mitsuba 3 time / jkatana time at equal ΔE2000, from one run).

Example::

    t = timeit(lambda: shade(x), repeats=5)
    rows.append(record("bench_render", {"spp": 16}, time_s=t,
                       error={"dE2000_mean": 0.8, "dE2000_p95": 2.1},
                       reference="4096 spp", study="samples per pixel",
                       variant="16 spp, importance", error_metric="dE2000_mean",
                       items=width * height, tolerance=1.0))
"""

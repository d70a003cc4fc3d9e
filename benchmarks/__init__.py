"""jkatana's benchmark suite: what accuracy costs in time.

Each ``benchmarks/bench_*.py`` module defines ``run(quick: bool) -> list[dict]``
returning records made with :func:`benchmarks._harness.record`. The runner
(``python -m benchmarks`` or ``jkatana bench``) runs every module in its own
subprocess, so peak memory and JIT caches are per benchmark, and writes one
JSON results file with the machine's facts.
"""

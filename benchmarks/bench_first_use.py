"""First use and second use: the time and peak memory of a command meeting a new input on an empty cache.

Each case is the command line a user runs, in its own process (peak RSS from ``os.wait4``), with an empty
``$JKATANA_CACHE`` holding JAX's persistent compile cache too; then the same command again in the same cache
(the second use). Cases:

- a new HDR (the shared ``pedestrian_overpass_1k.hdr``; full run: also resized with OpenImageIO to 2k,
  2048×1024, and to 6000×3000) through ``render`` (prefiltered; reference at 16 spp) and ``view --offscreen
  --frames 1``, the built-in blade at 400×300. Every command gets ``--max-memory`` of at most 60 % of the
  memory available when the run starts (and at most 10 GiB): a map whose estimate
  (:mod:`jkatana.render.memory`) does not fit is recorded as refused, with the estimate and the one-line
  refusal, instead of being run;
- a new lobe family in ``view`` (a hiraji parameter file of GGX, GTR and a two-lobe sum, :data:`FAMILIES`: the
  tables of its lobe are built on first use) and a new material in ``render`` (the GGX file, prefiltered:
  levels prefiltered with that lobe) — full run only;
- a new mesh through ``jkatana shape`` (the shared hammer scan, CC BY 4.0, Andrea Spognetta).

A map whose whole spectra do not fit the budget is streamed (:mod:`jkatana.render.streamed`): its records
carry the environment the frame reports (``env``: factored, channels, and ``rank_residual``, the low-rank
error measured against exact spectra). Full run also: the 6000×3000 map as a 61-band spectral EXR (written in
row blocks from the HDR's chromaticity-table spectra, :func:`jkatana.light.spectral_exr.write_spectral_exr_rows`)
through ``render`` prefiltered (``BENCH_FIRST_USE_SPECTRAL_EXR``: such a file written before).
``BENCH_FIRST_USE_MAPS`` (comma-separated labels, e.g. ``6000×3000,families``) keeps only those maps' cases
(``families``: the lobe families' and the new material's); ``BENCH_FIRST_USE_SPECTRAL_EXR=skip`` leaves the
spectral EXR out.

Quick mode (CI): the 1k map resized to 256×128 through ``render`` prefiltered at 160×120, the 6000×3000 map's
refusal by ``render`` under ``--max-memory 2G``, and ``shape``. Every record carries the estimate beside the
measured peak.
``python benchmarks/bench_first_use.py --plot RESULTS.json OUT.png`` draws time and peak memory against map size.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "import sys; from jkatana.cli import main; sys.exit(main())"]

_SCENE = """
[environment]
type = "{kind}"
path = "{path}"
{material}
[camera]
type = "orbit"
target = [0.45, -0.022, 0.0]
distance = 0.28
azimuth_deg = 20.0
elevation_deg = -40.0
roll_deg = 25.0
fov_deg = 30.0
resolution = [{w}, {h}]
[render]
mode = "prefiltered"
samples = 16
[output]
directory = "out"
name = "frame"
"""

#: Natural values of the parameter files of each lobe family a first ``view`` meets (as ``jkatana fit --model``
#: writes them): GGX and Beckmann taps ship with the package, GTR's and a two-lobe's are built from their core.
FAMILIES = {"ggx": {"scale": 2000.0, "alpha": 0.06},
            "gtr": {"scale": 2000.0, "alpha": 0.06, "gamma": 1.5},
            "two-lobe": {"scale": 2000.0, "alpha": 0.06, "alpha_haze": 0.3, "weight": 0.9}}


#: A small Python process that runs the command and reports its wall time and peak RSS (``os.wait4``). Linux
#: carries a process's peak RSS across fork and exec, so a command started from this benchmark's own process
#: (JAX imported) would report at least that process's size: the wrapper starts it from a small one.
_WRAPPER = """
import json, os, subprocess, sys, time
argv, log, timeout = json.loads(sys.argv[1])
t0 = time.perf_counter()
with open(log, "w") as err:
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err)
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.perf_counter() - t0 > timeout:
            proc.kill()
            pid, status, usage = os.wait4(proc.pid, 0)
            break
        time.sleep(0.05)
print(json.dumps({"wall_s": time.perf_counter() - t0, "peak_kib": usage.ru_maxrss,
                  "rc": os.waitstatus_to_exitcode(status)}))
"""


def measure(argv: list[str], cache: Path, log: Path, timeout: float = 1800.0) -> dict:
    """Run ``argv`` in a child process with ``cache`` as its jkatana and JAX cache: wall time, peak RSS, exit
    status, the last stderr line."""
    env = dict(os.environ, JKATANA_CACHE=str(cache), JAX_COMPILATION_CACHE_DIR=str(cache / "jax"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("JKATANA_MAX_MEMORY", None)
    # Python writes and reads the package's bytecode as it does for a user (a first use writes it)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    r = subprocess.run([sys.executable, "-S", "-c", _WRAPPER, json.dumps([argv, str(log), timeout])],
                       capture_output=True, text=True, env=env, cwd=log.parent)
    res = json.loads(r.stdout.strip().splitlines()[-1])
    lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    return {"wall_s": round(res["wall_s"], 2), "peak_rss_mb": round(res["peak_kib"] / 1024, 1), "rc": res["rc"],
            "last_line": lines[-1][-400:] if lines else ""}


def resized_hdr(src: str, width: int, height: int, out: Path) -> Path:
    """``src`` resized with OpenImageIO (its default filter) to ``width × height``, written as Radiance HDR."""
    import OpenImageIO as oiio

    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(src), roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3))
    if not buf.write(str(out)):
        raise RuntimeError(f"writing {out}: {buf.geterror()}")
    return out


def spectral_exr(hdr: Path, out: Path) -> Path:
    """``hdr`` as a 61-band Fichet 2021 spectral EXR of the same size, written in row blocks: each texel's
    Jakob 2019 spectrum from the chromaticity table (:class:`jkatana.light.streaming.RGBRows`)."""
    import numpy as np

    from jkatana.light.spectral_exr import write_spectral_exr_rows
    from jkatana.light.streaming import RGBRows
    from jkatana.spectral import DEFAULT_GRID

    src = RGBRows(hdr, DEFAULT_GRID)
    eye = np.eye(DEFAULT_GRID.size)
    return write_spectral_exr_rows(out, src.height, src.width, DEFAULT_GRID, lambda a, b: src.project(a, b, eye),
                                   block=32)


def frame_environment(out: str | Path) -> dict | None:
    """The ``jkatana_environment`` a frame's EXR reports (channels, factored, rank_residual), or None."""
    import OpenImageIO as oiio

    for exr in sorted(Path(out).rglob("*.exr")):
        inp = oiio.ImageInput.open(str(exr))
        if inp is None:
            continue
        value = inp.spec().getattribute("jkatana_environment")
        inp.close()
        if value:
            info = json.loads(value)
            return {k: info.get(k) for k in ("channels", "factored", "rank_residual", "caps")}
    return None


def family_file(path: Path, model: str = "ggx") -> Path:
    """A hiraji parameter file of a ``model`` lobe (:data:`FAMILIES`), its ``lobe`` built by the fit model as
    ``jkatana fit`` does (:func:`validation.gl_agreement.params_file`)."""
    from validation.gl_agreement import params_file

    return Path(params_file(path, model, "hiraji", FAMILIES[model]))


def bench_budget() -> int:
    """``--max-memory`` given to every case: 60 % of the memory available now, at most 10 GiB."""
    from jkatana.io.limits import memory_budget

    return int(min(0.6 * memory_budget(), 10 * 2 ** 30))


def run(quick: bool) -> list[dict]:
    import shutil

    work = Path(tempfile.mkdtemp(prefix="bench_first_use-"))
    try:
        return _run(quick, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _run(quick: bool, work: Path) -> list[dict]:
    from benchmarks._harness import budget_s, record
    from jkatana.io.limits import human, memory_budget
    from jkatana.render.commands import render_memory
    from jkatana.render.memory import environment_estimate
    from jkatana.render.scenefile import load_scene
    from jkatana.shared import shared_data

    t_start = time.perf_counter()
    deadline = budget_s(math.inf)
    hdr = str(shared_data("envmaps", "pedestrian_overpass_1k.hdr"))
    limit = bench_budget()
    records = []
    w, h = (160, 120) if quick else (400, 300)
    big = ("6000×3000", resized_hdr(hdr, 6000, 3000, work / "map6k.hdr"))
    maps = [("256×128", resized_hdr(hdr, 256, 128, work / "map256.hdr")), big] if quick else \
        [("1k", Path(hdr)), big, ("2k", resized_hdr(hdr, 2048, 1024, work / "map2k.hdr"))]
    only = [m for m in os.environ.get("BENCH_FIRST_USE_MAPS", "").split(",") if m]
    maps = [m for m in maps if not only or m[0] in only]
    for model in FAMILIES:
        family_file(work / f"{model}.json", model)

    def scene_file(label, path, material="", tag=""):
        p = work / f"scene-{label.replace('×', 'x').replace(' ', '-')}{'-' + tag if tag else ''}.toml"
        p.write_text(_SCENE.format(kind="exr" if str(path).endswith(".exr") else "hdr", path=path,
                                   material=material, w=w, h=h))
        return p

    def case(kind, label, argv, scene, *, interactive=False, extra=None, uses=("first", "second"), cap=None):
        limit_here = limit if cap is None else min(limit, cap)
        if time.perf_counter() - t_start > 0.8 * deadline:
            print(f"bench_first_use: {kind} {label}: skipped (module budget)", file=sys.stderr)
            return
        sc = load_scene(scene) if scene is not None else None
        estimate = None
        if sc is not None:
            estimate = (environment_estimate(sc, interactive=True, max_memory=limit_here) if interactive
                        else render_memory(sc, max_memory=limit_here)[0])
        cache = work / f"cache-{len(records)}"
        cache.mkdir()
        runs = []
        for use in uses:
            # a second render renders again (--force: a batch skips the frames it finished) from the warm cache
            again = ["--force"] if runs and "render" in argv else []
            runs.append(measure(argv + again + (["--max-memory", str(limit_here)] if scene is not None else []), cache,
                                work / f"log-{len(records)}-{use}.txt"))
            if runs[-1]["rc"] != 0:
                break
        first = runs[0]
        refused = first["rc"] == 2 and "memory" in first["last_line"]
        size = None
        if sc is not None:
            from jkatana.render.memory import environment_resolution

            size = environment_resolution(sc.environment)
        row = record("bench_first_use", {"use": kind, "map": label, **(extra or {})},
                     time_s={"median": first["wall_s"]}, first_s=first["wall_s"],
                     first_peak_mb=first["peak_rss_mb"], rc=first["rc"], refused=refused,
                     second_s=runs[1]["wall_s"] if len(runs) > 1 else None, second_rc=runs[-1]["rc"],
                     second_peak_mb=runs[1]["peak_rss_mb"] if len(runs) > 1 else None,
                     estimate_mb=None if estimate is None else round(estimate / 2 ** 20, 1),
                     max_memory_mb=round(limit_here / 2 ** 20, 1) if scene is not None else None,
                     env=frame_environment(argv[argv.index("-o") + 1]) if "-o" in argv and scene else None,
                     texels=None if size is None else size[0] * size[1],
                     cache_mb=round(sum(p.stat().st_size for p in cache.rglob("*") if p.is_file()) / 2 ** 20, 1),
                     message=first["last_line"] if first["rc"] != 0 else None)
        records.append(row)
        est = "" if estimate is None else f", estimate {human(estimate)}"
        what = "refused" if refused else f"rc {first['rc']}"
        print(f"bench_first_use: {kind} {label}: first {first['wall_s']:.1f} s / {first['peak_rss_mb']:.0f} MB "
              f"({what}{est}); second {row['second_s']} s / {row['second_peak_mb']} MB", file=sys.stderr)

    print(f"bench_first_use: --max-memory {human(limit)} (available {human(memory_budget())})", file=sys.stderr)
    mesh = str(shared_data("scans", "hammer", "hammer.obj"))
    case("shape (new mesh)", "hammer.obj", CLI + ["shape", mesh, "-o", str(work / "hammer.ply")], None,
         extra={"mesh": "hammer.obj (CC BY 4.0, A. Spognetta)"}, uses=("first",) if quick else ("first", "second"))
    for label, path in maps:
        scene = scene_file(label, path)
        out = str(work / f"out-{label.replace('×', 'x')}")
        case("render prefiltered", label, CLI + ["render", str(scene), "-o", out + "-p", "--mode", "prefiltered"],
             scene, cap=2 * 2 ** 30 if quick and label == big[0] else None)
        if quick:  # CI: one first use and one refusal (the big map under 2 GiB)
            continue
        case("render reference", label, CLI + ["render", str(scene), "-o", out + "-r", "--mode", "reference",
                                               "--samples", "16"], scene)
        case("view", label, CLI + ["view", str(scene), "--offscreen", "--frames", "1", "-o", out + "-v"], scene,
             interactive=True)
    given = os.environ.get("BENCH_FIRST_USE_SPECTRAL_EXR")  # one written before (minutes), or "skip"
    if not quick and (not only or big[0] in only) and given != "skip":
        label = "6000×3000"
        scene = scene_file("6000×3000-61", Path(given) if given else spectral_exr(big[1], work / "map6k-61.exr"))
        case("render prefiltered, 61-band spectral EXR", label,
             CLI + ["render", str(scene), "-o", str(work / "out-6k-exr-p"), "--mode", "prefiltered"], scene)
    if not quick and (not only or "families" in only):
        for model in FAMILIES:
            scene = scene_file("1k", hdr, material=f'[material]\nmap = "builtin"\nhiraji = "{model}.json"', tag=model)
            out = str(work / f"out-{model}")
            case(f"view, new lobe family ({model})", "1k", CLI + ["view", str(scene), "--offscreen", "--frames",
                                                                  "1", "-o", out + "-v"], scene, interactive=True)
            if model == "ggx":
                case("render prefiltered, new material (ggx)", "1k",
                     CLI + ["render", str(scene), "-o", out + "-p", "--mode", "prefiltered"], scene)
    return records


def plot(results: dict | str | Path, path: str | Path) -> Path:
    """Time and peak memory of each first use against the map's texel count, one line per command; refused
    requests as crosses at their estimate; second uses dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    if not isinstance(results, dict):
        results = json.loads(Path(results).read_text())
    rows = results["benchmarks"]["bench_first_use"]["records"] if "benchmarks" in results else results
    rows = [r for r in rows if r.get("texels")]
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(12, 6.8))
    for i, use in enumerate(dict.fromkeys(r["case"]["use"] for r in rows)):
        mine = sorted((r for r in rows if r["case"]["use"] == use), key=lambda r: r["texels"])
        ran = [r for r in mine if not r["refused"] and r["rc"] == 0]
        refused = [r for r in mine if r["refused"]]
        colour = f"C{i}"
        x = [r["texels"] / 1e6 for r in ran]
        ax_t.plot(x, [r["first_s"] for r in ran], "o-", color=colour, label=f"{use}: first")
        ax_t.plot(x, [r["second_s"] for r in ran], "s--", color=colour, alpha=0.6, label=f"{use}: second")
        ax_t.plot([r["texels"] / 1e6 for r in refused], [r["first_s"] for r in refused], "x", color=colour, ms=10)
        ax_m.plot(x, [r["first_peak_mb"] / 1024 for r in ran], "o-", color=colour, label=f"{use}: measured")
        est = [r for r in mine if r.get("estimate_mb")]
        ax_m.plot([r["texels"] / 1e6 for r in est], [r["estimate_mb"] / 1024 for r in est], ":", color=colour,
                  alpha=0.8, label=f"{use}: estimate")
        ax_m.plot([r["texels"] / 1e6 for r in refused], [r["estimate_mb"] / 1024 for r in refused], "x",
                  color=colour, ms=10)
    limit = next((r["max_memory_mb"] for r in rows if r.get("max_memory_mb")), None)
    if limit:
        ax_m.axhline(limit / 1024, color="k", lw=0.8, ls="--", label="--max-memory given")
    ticks = {r["texels"] / 1e6: f"{r['case']['map']}\n{r['texels'] / 1e6:.2g} M" for r in rows}
    for ax in (ax_t, ax_m):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(list(ticks), list(ticks.values()))
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xlabel("map (texels)")
        ax.grid(True, which="major", alpha=0.3)
    ax_t.set_ylabel("wall time (s)")
    ax_t.set_title("time: first use (empty cache), second use")
    ax_m.set_ylabel("peak RSS / estimate (GiB)")
    ax_m.set_title("memory: first use; × = refused before work")
    for ax in (ax_t, ax_m):
        ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":  # python benchmarks/bench_first_use.py --plot RESULTS.json OUT.png
    if len(sys.argv) == 4 and sys.argv[1] == "--plot":
        print(plot(sys.argv[2], sys.argv[3]))
    else:
        print(__doc__.splitlines()[0], "\nusage: python -m benchmarks --only bench_first_use; "
              "python benchmarks/bench_first_use.py --plot RESULTS.json OUT.png", file=sys.stderr)
        sys.exit(2)

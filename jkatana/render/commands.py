"""CLI commands of the render stage: ``jkatana demo`` and ``jkatana render``.

JAX is imported only inside the commands, after ``XLA_FLAGS`` asks for the
host devices a frame's pixels are split over (``--devices``, default one:
``--xla_force_host_platform_device_count``; :mod:`jkatana.render.frame`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from jkatana.render.integrators import INTEGRATORS, mode_help

DEMO_HELP = "Render the built-in blade under the built-in sky (reference mode, PNG + EXR)."
RENDER_HELP = "Render a scene TOML: one frame, or a batch of views × lightings (resumable, optional Dask)."


#: Host devices a frame's pixels are split over unless ``--devices`` asks for more (see :func:`_setup_devices`).
DEFAULT_DEVICES = 1


def _setup_devices(n: int | None = None) -> None:
    """Ask XLA for ``n`` host devices (default :data:`DEFAULT_DEVICES`) to split a frame's pixels over; must run
    before JAX is imported. One device already shades on every core (XLA's own thread pool); each further device
    holds its own copy of the environment (0.55 GB more for the streamed 6000×3000 map's second ``render``, and
    no faster on 2 cores), so more are asked for only with ``--devices``."""
    if "jax" in sys.modules:
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        n = max(1, int(n or DEFAULT_DEVICES))
        os.environ["XLA_FLAGS"] = (flags + f" --xla_force_host_platform_device_count={n}").strip()


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _check_common(args) -> None:
    """``--samples`` and ``--devices`` in range (before JAX starts: XLA crashes on absurd device counts)."""
    from jkatana.io.limits import number

    number(args.samples, "--samples", lo=1, hi=2 ** 16, integer=True)
    cores = _cores()
    number(args.devices, "--devices", lo=1, hi=max(8, 4 * cores), integer=True)


def render_memory(scene, *, samples=None, devices=None, max_memory=None) -> tuple[float, str, str]:
    """Estimated peak bytes of a frame of ``scene``, the field whose part dominates and what that part is.

    The estimate counts the arrays a frame allocates: the G-buffer and film (per pixel ~40 float64
    values, XYZ and, for spectral output, one float32 per band), the environment's preparation (its
    size read from the file's header: the upsampled map, its float64 copies, the sun split, the
    sampling tables and levels; :mod:`jkatana.render.memory`; once per host device, each holding its
    copy), and one shading call (``devices × chunk``
    pixels × bands, ~16 float32 temporaries, plus ~32 bytes per sample), on top of the process itself
    (:data:`jkatana.render.memory.BASE_BYTES`).
    """
    from jkatana.render.memory import BASE_BYTES, describe, environment_bytes, environment_field

    w, h = scene.camera.resolution
    bands = scene.spectral.grid.size
    samples = int(samples or scene.render.samples)
    devices = int(devices or DEFAULT_DEVICES)
    env_bytes = environment_bytes(scene.environment, bands, max_memory=max_memory)
    parts = {
        "camera.resolution": (w * h * (40 * 8 + 3 * 8 + (4 * bands if scene.output.spectral else 0)),
                              f"a {w}×{h} frame"),
        environment_field(scene.environment): (devices * env_bytes, describe(scene.environment, bands)
                                               + (f" on each of {devices} devices" if devices > 1 else "")),
        "render.chunk": (devices * min(scene.render.chunk, w * h) * bands * 4 * 16,
                         f"{devices} × {scene.render.chunk} pixels per shading call"),
        "--samples": (devices * samples * 32, f"{samples} samples per pixel"),
    }
    field = max(parts, key=lambda k: parts[k][0])
    return BASE_BYTES + sum(v for v, _ in parts.values()), field, parts[field][1]


def check_render_memory(scene, *, samples=None, devices=None, max_memory=None) -> float:
    """Refuse, naming the field that dominates, a frame whose estimated peak memory (:func:`render_memory`)
    exceeds the budget; returns the estimate in bytes."""
    from jkatana.io.limits import require_memory

    total, field, what = render_memory(scene, samples=samples, devices=devices, max_memory=max_memory)
    require_memory(total, field, f"{what} (the whole frame)", max_memory)
    return total


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=tuple(INTEGRATORS), default=None, help=mode_help())
    p.add_argument("--samples", type=int, default=None, help="samples per pixel (default: the scene's)")
    p.add_argument("--devices", type=int, default=None,
                   help="host devices to split a frame's pixels over (default 1: it shades on every core already; "
                        "each further device holds its own copy of the environment)")


def __getattr__(name: str):
    """``LIGHT_HELP``, the help of ``jkatana light`` (which runs from here: :func:`light_run`), read from
    :mod:`jkatana.light.commands` when asked for: importing the light stage imports JAX, which must wait until
    :func:`_setup_devices` has set ``XLA_FLAGS`` (PEP 562)."""
    if name == "LIGHT_HELP":
        from jkatana.light.commands import LIGHT_HELP

        return LIGHT_HELP
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def light_add_arguments(p: argparse.ArgumentParser) -> None:
    """``jkatana light``'s arguments (:mod:`jkatana.light.commands`)."""
    from jkatana.light.commands import light_add_arguments as add

    f = add(p).add_parser("prefilter", help="build a scene's environment (spectra, prefiltered levels, and the "
                                            "sampling tables for a mode that samples it) into the render cache; "
                                            "later renders of the scene load it at once")
    f.add_argument("scene", help="scene TOML")
    f.add_argument("--mode", default="prefiltered", choices=tuple(INTEGRATORS),
                   help="the render mode to prepare for (default prefiltered: also builds the prefiltered levels)")


def light_run(args: argparse.Namespace) -> int:
    """``jkatana light``: ``prefilter`` builds a scene's environment for a render mode with the renderer's own
    preparation (:func:`jkatana.render.renderer.prepare`) into the render cache; the other subcommands are the
    light stage's (:func:`jkatana.light.commands.light_run`)."""
    if args.light_command != "prefilter":
        from jkatana.light.commands import light_run as run

        return run(args)
    from jkatana.light.cache import cache_root
    from jkatana.render.renderer import prepare
    from jkatana.render.scenefile import load_scene

    from jkatana.render.memory import check_environment_memory

    scene = load_scene(args.scene)
    check_environment_memory(scene, max_memory=getattr(args, "max_memory", None))
    t0 = time.perf_counter()
    prepare(scene, mode=args.mode, max_memory=getattr(args, "max_memory", None))
    print(f"{args.scene}: environment for mode {args.mode} built in {time.perf_counter() - t0:.1f} s and cached "
          f"in {cache_root()}; renders of this scene load it from there")
    return 0


def demo_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), default=None,
                   help="image size (default 800 600)")
    _common(p)


def demo_run(args: argparse.Namespace) -> int:
    from jkatana.io.limits import numbers
    from jkatana.io.outputs import Output, check_outputs

    t_start = time.perf_counter()
    _check_common(args)
    numbers(args.resolution, "--resolution", lo=1, hi=2 ** 15, integer=True)
    check_outputs([Output(args.output, "--output", folder=True)])
    _setup_devices(args.devices)
    from jkatana.render.scenefile import DEMO_SCENE, scene_from_dict

    raw = {k: dict(v) if isinstance(v, dict) else v for k, v in DEMO_SCENE.items()}
    raw["output"] = {"directory": str(Path(args.output)), "name": "demo"}
    if args.resolution:
        raw["camera"] = {**raw["camera"], "resolution": list(args.resolution)}
    scene = scene_from_dict(raw)
    check_render_memory(scene, samples=args.samples, devices=args.devices, max_memory=args.max_memory)
    from jkatana.render.renderer import prepare, render_view, write_outputs

    t0 = time.perf_counter()
    prep = prepare(scene, mode=args.mode, samples=args.samples, max_memory=args.max_memory)
    t1 = time.perf_counter()
    frame = render_view(prep)
    t2 = time.perf_counter()
    stem = Path(scene.output.directory) / scene.output.name
    paths = write_outputs(prep, frame, stem, {"jkatana_cold_start_s": round(t2 - t_start, 2)})
    t3 = time.perf_counter()
    w, h = scene.camera.resolution
    p = prep.plan
    print(f"jkatana demo: built-in blade, Hosek–Wilkie sky, {p.mode} mode, {p.samples} spp, {w}×{h}, "
          f"{prep.grid.size} bands, {frame.stats['pixels_shaded']} blade pixels")
    print(f"  wrote {paths['png']}")
    print(f"  wrote {paths['exr']}  (linear CIE XYZ, scene/grid/samples/timing in the header)")
    print(f"  time: start-up {t0 - t_start:.1f} s, scene {t1 - t0:.1f} s, frame {t2 - t1:.1f} s "
          f"(G-buffer {frame.timing['gbuffer_s']:.1f} s, shading incl. JIT {frame.timing['shade_s']:.1f} s), "
          f"write {t3 - t2:.1f} s; total {t3 - t_start:.1f} s")
    return 0


def render_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene TOML file (schema: jkatana.render.scenefile)")
    p.add_argument("--views", type=int, default=1, help="camera azimuths evenly around the target")
    p.add_argument("--lights", type=int, default=1, help="environment rotations evenly about +Y")
    p.add_argument("-o", "--output", default=None, help="output folder (default: the scene's)")
    p.add_argument("--force", action="store_true", help="re-render finished frames")
    p.add_argument("--dask", action="store_true",
                   help="distribute frames with Dask (a LocalCluster unless --scheduler is given)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address (implies --dask)")
    p.add_argument("--workers", type=int, default=1, help="LocalCluster worker processes (with --dask)")
    _common(p)


def render_run(args: argparse.Namespace) -> int:
    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    _check_common(args)
    number(args.views, "--views", lo=1, hi=100000, integer=True)
    number(args.lights, "--lights", lo=1, hi=100000, integer=True)
    number(args.workers, "--workers", lo=1, hi=max(8, 4 * _cores()), integer=True)
    if args.scheduler is not None and ("\x00" in args.scheduler or not args.scheduler.strip()):
        from jkatana.errors import InputError
        raise InputError(f"not a scheduler address: {args.scheduler!r}", field="--scheduler")
    _setup_devices(args.devices)
    from jkatana.render.batch import plan_batch, run_batch_dask, run_batch_serial, summary_table
    from jkatana.render.scenefile import load_scene

    scene = load_scene(args.scene)
    if args.output:
        scene = scene.with_output_directory(args.output)
    name = str(scene.output.name)
    if name in ("", ".", "..") or "/" in name or "\x00" in name:
        from jkatana.errors import InputError
        raise InputError(f"not a file name: {name!r}", path=args.scene, field="output.name")
    check_outputs([Output(scene.output.directory, "--output", folder=True)], inputs=[args.scene])
    check_render_memory(scene, samples=args.samples, devices=args.devices, max_memory=args.max_memory)
    jobs = plan_batch(scene, args.views, args.lights)
    if args.dask or args.scheduler:
        results = run_batch_dask(args.scene, scene, jobs, mode=args.mode, samples=args.samples,
                                 force=args.force, scheduler=args.scheduler, workers=args.workers)
    else:
        results = run_batch_serial(scene, jobs, mode=args.mode, samples=args.samples, force=args.force,
                                   max_memory=args.max_memory)
    print(summary_table(results))
    return 0

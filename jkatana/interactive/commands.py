"""CLI: ``jkatana view [SCENE]`` (window) and ``jkatana view [SCENE] --offscreen --frames N -o DIR``."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

VIEW_HELP = "Interactive spectral view of the blade (pyrender + GLSL baked from the models); --offscreen for PNGs."


def view_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="?", default=None,
                   help="scene TOML (jkatana.render schema); default: built-in blade, map and environment")
    p.add_argument("--env", choices=("sky", "sun", "studio"), default="sky",
                   help="built-in environment when no SCENE is given (default sky)")
    p.add_argument("--offscreen", action="store_true", help="render an orbit to PNGs headless (EGL/OSMesa)")
    p.add_argument("--closeup", action="store_true",
                   help="start from a close-up in which the flat fills the frame (as appraisers look)")
    p.add_argument("--frames", type=int, default=8, help="offscreen: number of orbit frames (default 8)")
    p.add_argument("-o", "--output", default="out/view", help="folder for PNGs (default out/view)")
    p.add_argument("--rank", type=int, default=2, choices=(1, 2, 3, 4),
                   help="rank of the spectral basis of the Fresnel term: one 3-D environment fetch per rank and "
                        "tap; higher is closer to the exact spectra and slower (default 2)")
    p.add_argument("--taps", type=int, default=3, choices=(1, 3, 5),
                   help="environment taps per pixel for the rough lobe: 1 isotropic (fastest, least accurate), "
                        "3 taps along the plane of incidence with offsets, weights and filter width fitted to "
                        "the lobe per view angle (default), 5 binomial taps matching the lobe's mean and variance "
                        "(slowest)")
    p.add_argument("--flat-background", action="store_true",
                   help="a flat grey behind the blade instead of the environment (coverage checks, screenshots)")
    p.add_argument("--no-rough", action="store_true", help="mirror-like lobes (skip the roughness blur)")
    p.add_argument("--no-blend", action="store_true", help="hiraji everywhere (ignore the map's w)")
    p.add_argument("--forward", action="store_true",
                   help="shade in the forward pass instead of deferred (slower on software GL; for comparison)")
    p.add_argument("--refresh", type=float, default=60.0, help="window: redraw rate in Hz (default 60)")
    p.add_argument("--measure-fps", type=int, default=0, metavar="N",
                   help="window: draw N frames back to back (the light turning; at --drag-scale), print the frame "
                        "rate, close")
    p.add_argument("--drag-scale", default="auto", metavar="S",
                   help="window: while a mouse button is held, shade at S × the resolution and scale up (0 < S ≤ 1; "
                        "0.5 shades a quarter of the pixels); 'auto' (default): the fraction that fits the --refresh "
                        "interval, from the measured full-resolution frame (1 when that fits); 1: always full "
                        "resolution. Still frames are always full resolution")
    p.add_argument("--exposure", type=float, default=None, help="exposure (default: the scene's, or auto)")
    p.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), default=None)
    p.add_argument("--msaa", type=int, default=0, help="offscreen MSAA samples (default 0; pyrender uses 4)")
    p.add_argument("--screenshot", default=None,
                   help="window: save the 3rd frame (with --measure-fps: the last measured one) to this PNG and close")


def _load(args):
    from jkatana.interactive import scene as S
    from jkatana.interactive.exposure import auto_exposure

    if args.scene is None:
        sc = S.default_scene(args.env)
    else:
        if not Path(args.scene).exists():
            from jkatana.errors import InputError
            raise InputError("scene file not found", path=args.scene)
        sc = S.from_render_scene(args.scene)
    if args.resolution:
        w, h = args.resolution
        sc.view = S.View(sc.view.pose, sc.view.yfov, int(w), int(h))
    if args.closeup:
        sc.view = S.closeup_view(sc.mesh, sc.view.width, sc.view.height)
    if args.exposure is not None:
        sc.exposure = args.exposure
    sc.auto_exposure = sc.exposure != sc.exposure  # NaN: "auto"
    if sc.auto_exposure:  # a first guess; the first frames then set it by the rule `render` uses (exposure.calibrate_exposure)
        sc.exposure = auto_exposure(sc.exposure_radiance(), sc.grid)
    return sc


def _state(sc, args, glrender):
    from jkatana.interactive.bake import cached_bake

    t = time.perf_counter()
    baked = cached_bake(sc.radiance if sc.env_rows is None else sc.env_rows, sc.grid, rank=max(args.rank, 3),
                        colourspace=sc.colourspace,
                        transfer=sc.transfer, source=sc.source, progress=True, lobes=sc.lobes, stack_rank=args.rank)
    print(f"[view] tables baked/loaded in {time.perf_counter() - t:.1f} s (rank {baked.rank}, "
          f"{len(baked.mus)} μ levels, Fresnel rank-{baked.rank} max rel. error {baked.fresnel_err:.1e})",
          file=sys.stderr)
    st = glrender.ShadingState(baked, sc.refl_map, exposure=sc.exposure, rank=args.rank, rough=not args.no_rough,
                               blend=not args.no_blend, two_tap=args.taps != 1, taps=max(args.taps, 3))
    st.env_rotation = sc.env_rotation
    st.background = not args.flat_background  # the environment behind the blade, as `render` shows it
    return st


def _offscreen(args) -> int:
    from jkatana.interactive.exposure import calibrate_exposure
    from jkatana.interactive.gl import GLUnavailable

    sc = _load(args)
    out = Path(args.output)
    try:
        from jkatana.interactive import glrender
        st = _state(sc, args, glrender)
        r = glrender.BakedOffscreenRenderer(st, sc.view.width, sc.view.height, samples=args.msaa,
                                            deferred=False if args.forward else None)
    except GLUnavailable as err:
        print(f"jkatana view: {err}", file=sys.stderr)
        return _fallback(args, out)
    from PIL import Image
    from tqdm import tqdm

    from jkatana.io.atomic import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    times = []
    scene = glrender.build_scene(sc.mesh, sc.view)
    cam = next(iter(scene.camera_nodes))
    if sc.auto_exposure and r._r._renderer.deferred:
        e = calibrate_exposure(lambda: (r.render(scene, mask=True), r.last_mask), st, sc.colourspace, sc.transfer)
        print(f"[view] exposure {e:.4g} (the rule `render` uses: jkatana.render.film.scene_exposure)",
              file=sys.stderr)
    for k, v in enumerate(tqdm(sc.orbit(args.frames), desc="frames", file=sys.stderr)):
        scene.set_pose(cam, v.pose)
        t = time.perf_counter()
        img = r.render(scene)
        times.append(time.perf_counter() - t)
        with atomic_path(out / f"frame_{k:04d}.png") as tmp:
            Image.fromarray(img).save(tmp, format="PNG")
    r.delete()
    if len(times) > 1:
        steady = sorted(times[1:])[(len(times) - 1) // 2]
        timing = f"median {steady * 1e3:.1f} ms/frame over {len(times) - 1} frames after the first (incl. read-back)"
    else:
        timing = f"one frame in {times[0] * 1e3:.1f} ms (the first frame includes setup; no steady rate measured)"
    print(f"jkatana view: {len(times)} frames {sc.view.width}×{sc.view.height} → {out}/frame_*.png; {timing}, "
          f"platform {os.environ.get('PYOPENGL_PLATFORM')}")
    return 0


def _fallback(args, out: Path) -> int:
    """No GL: render the same orbit with the JAX reference renderer (jkatana.render), if present."""
    try:
        from jkatana.render.renderer import prepare, render_view, write_outputs
        from jkatana.render.scenefile import DEMO_SCENE, load_scene, scene_from_dict
    except ImportError:
        print("jkatana view: no GL and the reference renderer (jkatana.render) is not installed", file=sys.stderr)
        return 1
    print("jkatana view: falling back to the JAX reference renderer (slow; one frame per view)", file=sys.stderr)
    if args.scene:
        scene = load_scene(args.scene)
        raw = scene.to_dict()
        path = Path(args.scene)
    else:
        raw = {k: dict(v) if isinstance(v, dict) else v for k, v in DEMO_SCENE.items()}
        path = None
    if args.resolution:
        raw["camera"] = {**raw.get("camera", {}), "resolution": list(args.resolution)}
    scene = scene_from_dict(raw, path)
    prep = prepare(scene)
    out.mkdir(parents=True, exist_ok=True)
    for k in range(args.frames):
        frame = render_view(prep, view=k, views=args.frames)
        write_outputs(prep, frame, out / f"frame_{k:04d}")
    print(f"jkatana view: {args.frames} reference frames → {out}")
    return 0


def _check(args) -> None:
    """Every number of ``view`` in range, the frame's memory within the budget, outputs writable."""
    from jkatana.io.limits import number, numbers, require_memory
    from jkatana.io.outputs import Output, check_outputs

    number(args.frames, "--frames", lo=1, hi=100000, integer=True)
    number(args.measure_fps, "--measure-fps", lo=0, hi=100000, integer=True)
    number(args.refresh, "--refresh", lo=0, lo_open=True, hi=1e6)
    number(args.exposure, "--exposure", lo=0, lo_open=True)
    number(args.msaa, "--msaa", lo=0, hi=16, integer=True)
    frame = 0
    if args.resolution:
        w, h = numbers(args.resolution, "--resolution", lo=1, hi=16384, integer=True)
        # RGBA8 colour, depth and the deferred G-buffer (about 16 float32 per pixel), MSAA multiplies
        frame = w * h * 80 * max(1, args.msaa)
        require_memory(frame, "--resolution", f"a {w}×{h} view", getattr(args, "max_memory", None))
    if args.scene is not None and Path(args.scene).is_file():
        # the environment's load and bake, from its header's size, before any of it is read
        from jkatana.render.memory import check_environment_memory
        from jkatana.render.scenefile import load_scene

        check_environment_memory(load_scene(args.scene), interactive=True, extra=frame,
                                 max_memory=getattr(args, "max_memory", None))
    outs = [Output(args.output, "--output", folder=True)]
    if args.screenshot:
        outs.append(Output(args.screenshot, "--screenshot", (".png",)))
    check_outputs(outs, inputs=[args.scene])


def view_run(args: argparse.Namespace) -> int:
    from jkatana.errors import InputError

    _check(args)
    if args.drag_scale != "auto":
        try:
            args.drag_scale = float(args.drag_scale)
        except ValueError:
            args.drag_scale = float("nan")
        if not 0 < args.drag_scale <= 1:
            raise InputError(f"--drag-scale must be in (0, 1] or 'auto', got {args.drag_scale}", field="--drag-scale")
    if args.drag_scale != 1 and args.forward:
        raise InputError("--drag-scale needs the deferred path (drop --forward)", field="--drag-scale")
    if args.offscreen:
        return _offscreen(args)
    from jkatana.interactive.gl import GLUnavailable, missing_package

    if not os.environ.get("DISPLAY"):
        print("jkatana view: no X display (DISPLAY unset); use --offscreen, or run under Xvfb "
              "(Debian package xvfb: xvfb-run jkatana view ...)", file=sys.stderr)
        return 2
    pkg = missing_package("window")
    if pkg:
        print(f"jkatana view: no OpenGL library; install the Debian package {pkg}", file=sys.stderr)
        return 2
    sc = _load(args)
    try:
        from jkatana.interactive import viewer
        from jkatana.interactive import glrender
    except GLUnavailable as err:
        print(f"jkatana view: {err}", file=sys.stderr)
        return 2
    st = _state(sc, args, glrender)
    scene = glrender.build_scene(sc.mesh, sc.view)
    viewer.BladeViewer(scene, st, viewport_size=(sc.view.width, sc.view.height), out_dir=args.output,
                       screenshot=args.screenshot, title=f"jkatana view — {sc.name}", deferred=not args.forward,
                       refresh_rate=args.refresh, measure_frames=args.measure_fps, drag_scale=args.drag_scale,
                       calibrate=(sc.colourspace, sc.transfer) if sc.auto_exposure else None)
    return 0


def run_in_xvfb(argv: list[str], timeout: float = 120.0, size=(800, 600)) -> subprocess.CompletedProcess:
    """Run ``jkatana view`` in a fresh process on a private Xvfb display (tests, headless CI)."""
    import shutil
    import tempfile

    if shutil.which("Xvfb") is None:
        raise FileNotFoundError("Xvfb not found; install the Debian package xvfb")
    # -displayfd: Xvfb picks a free display itself and writes its number once it accepts connections
    # (no race with other Xvfb servers started at the same moment, no polling for the socket)
    import select

    rfd, wfd = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(wfd), "-screen", "0", f"{size[0] + 64}x{size[1] + 64}x24",
                             "-nolisten", "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            pass_fds=(wfd,))
    os.close(wfd)
    try:
        ready, _, _ = select.select([rfd], [], [], 60.0)
        disp = os.read(rfd, 64).decode().strip() if ready else ""
        if not disp.isdigit():
            raise RuntimeError(f"Xvfb did not start (exit status {xvfb.poll()})")
        env = dict(os.environ, DISPLAY=f":{disp}")
        env.pop("PYOPENGL_PLATFORM", None)
        with tempfile.TemporaryDirectory():
            return subprocess.run([sys.executable, "-m", "jkatana.cli", "view", *argv], env=env,
                                  capture_output=True, text=True, timeout=timeout)
    finally:
        os.close(rfd)
        xvfb.terminate()
        xvfb.wait(timeout=10)

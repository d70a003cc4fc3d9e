"""CLI command ``jkatana export``: a scene TOML (with the parameter files, map and mesh it names) as the scene
file and assets of another renderer: Mitsuba 3 (:mod:`jkatana.export.mitsuba`), glTF 2.0
(:mod:`jkatana.export.gltf`) or pbrt-v4 (:mod:`jkatana.export.pbrt`).

The output folder must not exist: everything is written into a temporary folder beside it, which becomes
the output folder only when complete (:func:`jkatana.io.atomic.atomic_folder`), so an interrupted or
refused export leaves nothing, and nothing is overwritten.
"""

from __future__ import annotations

import argparse
from pathlib import Path

EXPORT_HELP = ("Export a scene to another renderer: Mitsuba 3 (XML + PLY/EXR/.bsdf), glTF 2.0 (.glb) or "
               "pbrt-v4 (.pbrt); what is exact and what is approximated is written beside it.")
TARGETS = ("mitsuba", "gltf", "pbrt")


def export_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="?", default=None,
                   help="scene TOML (jkatana.render schema); default: the built-in demo scene")
    p.add_argument("--to", dest="target", choices=TARGETS, required=True, help="the renderer to export to")
    p.add_argument("-o", "--output", required=True, help="output folder (must not exist)")
    p.add_argument("--spp", type=int, default=None,
                   help="mitsuba, pbrt: samples per pixel written into the scene (default: the scene's)")


def _exists(out: Path):
    from jkatana.errors import InputError

    return lambda: InputError("output folder exists: nothing was overwritten (choose a new folder)", path=out,
                              field="--output")


def export_scene(scene, target: str, out: Path, *, spp: int | None = None) -> dict:
    """Export a loaded :class:`jkatana.render.scene.Scene` to ``target`` in the new folder ``out``."""
    from jkatana.io.atomic import atomic_folder

    out = Path(out)
    if target == "gltf":
        from jkatana.export.gltf import export_gltf

        if out.exists() or out.is_symlink():
            raise _exists(out)()
        return export_gltf(scene, out)
    with atomic_folder(out, exists_error=_exists(out)) as tmp:
        if target == "mitsuba":
            from jkatana.export.mitsuba import export_mitsuba

            return export_mitsuba(scene, tmp, spp=spp)
        from jkatana.export.pbrt import export_pbrt

        return export_pbrt(scene, tmp, spp=spp)


def export_run(args: argparse.Namespace) -> int:
    from jkatana.io.limits import number
    from jkatana.render.scenefile import default_scene, load_scene

    if args.spp is not None:
        number(args.spp, "--spp", lo=1, hi=2 ** 16, integer=True)
    scene = default_scene() if args.scene is None else load_scene(args.scene)
    summary = export_scene(scene, args.target, Path(args.output), spp=args.spp)
    notes = summary.get("approximations") or summary.get("approximated") or []
    print(f"jkatana export: wrote {args.output} ({args.target})"
          + (f"; approximated: {len(notes)} item(s), see the notes file there" if notes else ""))
    return 0

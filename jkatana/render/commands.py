"""CLI commands of the render stage: ``jkatana demo`` and ``jkatana render``."""

from __future__ import annotations

import argparse

DEMO_HELP = "Render the built-in blade under the built-in sky (PNG + EXR)."


def demo_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder")


def demo_run(args: argparse.Namespace) -> int:
    """Until the renderer lands: print each region's spectral reflectance and sRGB colour."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from jkatana.models import Conductor, in_plane
    from jkatana.spectral import DEFAULT_GRID, illuminant, spectrum_to_xyz, to_display

    conductor = Conductor.from_table("Fe-Johnson")
    L, V = in_plane(jnp.deg2rad(35.0), jnp.deg2rad(35.0))
    F = np.asarray(conductor.fresnel(L[..., 2]))
    d65 = illuminant("D65")
    xyz = spectrum_to_xyz(F * d65, normalise_to=d65)
    rgb = to_display(xyz)
    print("iron (Johnson & Christy 1974), specular reflectance at 35°:")
    for wl, f in zip(DEFAULT_GRID.wavelengths[::10], F[::10]):
        print(f"  {wl:5.0f} nm  {f:.4f}")
    print(f"  sRGB under D65: {np.round(rgb * 255).astype(int).tolist()}")
    return 0

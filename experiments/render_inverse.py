"""Inverse rendering: recover a region's μ and χ from rendered images by differentiating the renderer.

Target: the sun's glint on a hiraji sphere (a 12° field around it) (χ = 79000, μ0 = 0.05, calibrated convention K = 1e5)
under the Hosek–Wilkie sky, rendered in the reference mode at 256 spp (seed A).
Fit: Levenberg–Marquardt (optimistix) on log μ, log χ, residuals = the image
rendered at 32 spp with other random numbers (seed B, fixed during the fit so
the objective is smooth) minus the target. Gradients/Jacobians through the
jitted shader (:func:`jkatana.render.shading.shade`).

Run: ``python experiments/render_inverse.py [--out out/experiments]``; prints
the recovered values and writes a PNG (target | start | recovered | 10× |residual|).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

from jkatana.light.sky import hosek_wilkie_sky  # noqa: E402
from jkatana.models import Conductor  # noqa: E402
from jkatana.render.camera import Camera  # noqa: E402
from jkatana.render.film import display, film_weights, write_png  # noqa: E402
from jkatana.render.gbuffer import gbuffer_sphere  # noqa: E402
from jkatana.render.environment import build_environment  # noqa: E402
from jkatana.render.fresnel_fold import Material, fresnel_table  # noqa: E402
from jkatana.render.plan import Pixels, Plan  # noqa: E402
from jkatana.render.shading import shade  # noqa: E402
from jkatana.spectral import DEFAULT_GRID  # noqa: E402

TRUE = {"mu": 0.05, "chi": 79000.0}
START = {"mu": 0.10, "chi": 40000.0}
K = 1.0e5


def main(out: Path, size: int = 40) -> dict:
    dtype = jnp.float64
    env_rad = np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, (64, 128), DEFAULT_GRID).radiance)
    env, _, _ = build_environment(env_rad, dtype=dtype)
    c = Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=dtype)
    # look at the sun's glint with a narrow field, so that the lobe (μ ≈ 3°) spans many pixels
    from jkatana.light.sky import sun_direction

    eye = np.array([0.0, 0.4, 3.2])
    s = np.asarray(sun_direction(35.0, 160.0), np.float64)
    n = s / np.linalg.norm(s) + eye / np.linalg.norm(eye)
    n /= np.linalg.norm(n)
    cam = Camera(position=tuple(eye), look_at=tuple(n), fov_deg=12.0, width=size, height=size)
    gb = gbuffer_sphere(cam)
    m = gb.mask.reshape(-1)
    take = lambda a, k: jnp.asarray(a.reshape(-1, k)[m], dtype)  # noqa: E731
    P = int(m.sum())
    cmf = jnp.asarray(film_weights(DEFAULT_GRID), dtype)
    plan_ref = Plan(samples=256, hiraji=True, hamon=False, calibration=K)
    plan_fit = Plan(samples=32, hiraji=True, hamon=False, calibration=K)

    def render(plan, log_mu, log_chi, key):
        mu = jnp.exp(log_mu) * jnp.ones((P,), dtype)
        px = Pixels(take(gb.position, 3), take(gb.normal, 3), take(gb.view, 3), jnp.ones((P,), dtype), mu, mu)
        mat = Material(fresnel_table(c.n, c.k), jnp.exp(log_chi), jnp.asarray(43000.0, dtype))
        return shade(plan, mat, env, None, px, cmf, key)[0]

    target = jax.jit(lambda: render(plan_ref, jnp.log(TRUE["mu"]), jnp.log(TRUE["chi"]), jax.random.PRNGKey(1)))()
    scale = float(jnp.mean(target[:, 1]))

    def residuals(theta, _):
        return (render(plan_fit, theta[0], theta[1], jax.random.PRNGKey(2)) - target).reshape(-1) / scale

    theta0 = jnp.log(jnp.asarray([START["mu"], START["chi"]], dtype))
    t0 = time.perf_counter()
    sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), theta0, max_steps=100,
                             throw=False)
    dt = time.perf_counter() - t0
    mu, chi = (float(v) for v in jnp.exp(sol.value))
    result = {"true": TRUE, "start": START, "recovered": {"mu": mu, "chi": chi},
              "rel_error": {"mu": mu / TRUE["mu"] - 1, "chi": chi / TRUE["chi"] - 1},
              "steps": int(sol.stats["num_steps"]), "converged": bool(sol.result == optx.RESULTS.successful),
              "seconds": dt, "pixels": P}
    # picture: target | start | recovered | 10x residual
    out.mkdir(parents=True, exist_ok=True)

    def img(xyz):
        full = np.zeros((size * size, 3))
        full[m] = np.asarray(xyz)
        return full.reshape(size, size, 3)

    start_img = render(plan_fit, theta0[0], theta0[1], jax.random.PRNGKey(2))
    rec_img = render(plan_fit, sol.value[0], sol.value[1], jax.random.PRNGKey(2))
    ex = 0.8 / float(np.percentile(np.asarray(target[:, 1]), 99))
    panels = [display(img(x), exposure=ex) for x in (target, start_img, rec_img)]
    panels.append(display(img(10 * jnp.abs(rec_img - target)), exposure=ex))
    write_png(out / "render_inverse.png", np.concatenate(panels, axis=1), {"result": str(result)})
    return result


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/experiments")
    r = main(Path(ap.parse_args().out))
    print(r)

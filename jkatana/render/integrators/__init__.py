"""The shader's integrators: one strategy per render mode, in one registry.

Each mode of :func:`jkatana.render.shading.shade` is an integrator, the estimator of the
environment's share of the rendering equation for a G-buffer pixel, as pbrt-v4 gives each
light-transport algorithm an ``Integrator`` of its own (Pharr, Jakob & Humphreys 2023,
*Physically Based Rendering*, 4th ed., §1.3) and Mitsuba 3 a plugin per integrator
(``direct``, ``path``; Jakob et al. 2022). :data:`INTEGRATORS` maps each mode's name to its
:class:`Integrator`: what the rest of the renderer asks of the mode (the plan's mode list,
the scene file's and the command line's choices, which lobes it renders, how its frames are
split and cached) and the module that implements it. The registry is plain data, importable
without JAX (the command line lists the modes before JAX is imported); an implementation
module is imported on first use (:meth:`Integrator.strategy`).

An implementation module holds two functions of a :class:`~jkatana.render.integrators.base.Context`:

- ``radiance(ctx, acc)``: ``acc`` plus the mode's estimate of the lobes' environment
  integral (and of the split caps', where the mode integrates them itself);
- ``directions(ctx)``: ``(lobe, env)``, the world directions ``radiance`` looks the
  environment up along, ``(P, S, 3)`` each, for the host's visibility rays
  (:func:`jkatana.render.shading.ray_directions`).
"""

from __future__ import annotations

import dataclasses
import importlib


@dataclasses.dataclass(frozen=True)
class Integrator:
    """A render mode: its name, what it is, and what the renderer needs to know about it.

    **Fields:**

    - `name`: the mode's name (``Plan.mode``, ``[render] mode``, ``--mode``).
    - `module`: the implementing module under :mod:`jkatana.render.integrators`.
    - `summary`: one line for the command line's help.
    - `any_lobe`: renders a region's own lobe (``Plan.hiraji_lobe``/``hamon_lobe``), not only the paper's.
    - `sampled`: Monte Carlo: lobe and environment samples combined by multiple importance sampling.
    - `deterministic`: no noise: a pixel's value does not depend on the call or device that shades it.
    - `cap_rule`: integrates the environment's split caps by the deterministic cap rule
      (:func:`jkatana.render.caps.cap_rule_for`) rather than by sampling them.
    - `whole_map`: shades the whole map: refuses an environment with split caps.
    - `splits_sun`: by default the environment's compact sun is split off as a cap light.
    - `low_rank`: shades the environment projected on its first principal spectra (``[render] rank``).
    - `prefiltered`: reads the environment's prefiltered levels (built for the maps' widths).
    """

    name: str
    module: str
    summary: str
    any_lobe: bool = False
    sampled: bool = False
    deterministic: bool = False
    cap_rule: bool = False
    whole_map: bool = False
    splits_sun: bool = False
    low_rank: bool = False
    prefiltered: bool = False

    def strategy(self):
        """The implementing module (its ``radiance`` and ``directions``), imported on first use."""
        return importlib.import_module(f"{__name__}.{self.module}")


#: Every render mode, by name, in the order the command line lists them.
INTEGRATORS: dict[str, Integrator] = {i.name: i for i in (
    Integrator("reference", "mis", "lobe and environment importance sampling combined by MIS (unbiased)",
               any_lobe=True, sampled=True),
    Integrator("paper", "paper", "the paper's jittered rays about the mirror direction, Gaussian-weighted",
               cap_rule=True, splits_sun=True),
    Integrator("prefiltered", "prefiltered", "split sum: the environment prefiltered by the lobe (no noise)",
               any_lobe=True, deterministic=True, cap_rule=True, splits_sun=True, prefiltered=True),
    Integrator("lowrank", "mis", "reference on the environment's first principal spectra",
               any_lobe=True, sampled=True, splits_sun=True, low_rank=True),
    Integrator("paper-published", "paper", "the paper's 30 jittered lobe rays on the whole map, as published, "
               "which miss compact bright sources (a sun's glint can vanish)", whole_map=True),
)}


def integrator_for(mode: str) -> Integrator:
    """The registered integrator of ``mode`` (``Plan.mode``); a ``ValueError`` naming the modes for another name."""
    found = INTEGRATORS.get(mode)
    if found is None:
        raise ValueError(f"unknown render mode {mode!r}: one of {list(INTEGRATORS)}")
    return found


def mode_help() -> str:
    """The command line's ``--mode`` help: each mode's summary, and which split a compact sun off by default."""
    modes = "; ".join(f"{i.name}: {i.summary}" for i in INTEGRATORS.values())
    split = ", ".join(i.name for i in INTEGRATORS.values() if i.splits_sun)
    return (f"shading mode (default: the scene's). {modes}. {split} split a compact sun off the environment as a "
            "cap light by default")

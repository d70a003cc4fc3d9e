"""A lobe's identity: its family and parameters as one hashable value that makes its :class:`~jkatana.models.lobes.Lobe`.

A region's lobe reaches the shader from a parameter file's ``to_params()`` dict. On the way it must be
hashable (a static part of a compiled program and of the render and bake cache keys), at unit primary width
(one compiled program serves every per-pixel width of the reflectance map; the prefilter and the
interactive tables take a lobe as a family width ↦ lobe), and in the convention the frame renders
(energy-normalised without a calibration). :class:`LobeId` is that one value: it knows its family and
parameters, gives them back as a dict, and makes its lobe at any width.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from jkatana.models.lobes import LOBES, Lobe, _GaussianBase, lobe_from_params


def _freeze(v):
    if isinstance(v, dict):
        return LobeId.of(v)
    if isinstance(v, (bool, str)) or v is None:
        return v
    a = np.asarray(v, np.float64)
    if a.ndim:
        raise ValueError(f"a lobe identity needs scalar parameters, got shape {a.shape}")
    return float(a)


def _widths_of(params: dict) -> list[tuple[tuple[str, ...], str]]:
    """Paths ``(nested field names, width field)`` of every width in a ``to_params()`` dict, first part first."""
    cls = LOBES[params["lobe"]]
    out = [((), f) for f in cls.widths if f in params]
    for f in (fld.name for fld in dataclasses.fields(cls)):
        v = params.get(f)
        if isinstance(v, dict):
            out += [((f,) + path, w) for path, w in _widths_of(v)]
    return out


def _map_widths(params: dict, fn) -> dict:
    p = dict(params)
    for f in LOBES[p["lobe"]].widths:
        if f in p:
            p[f] = fn(p[f])
    for f, v in p.items():
        if isinstance(v, dict):
            p[f] = _map_widths(v, fn)
    return p


def normalised_params(params: dict) -> dict:
    """A ``to_params()`` dict with every Gaussian part in the normalised convention (scale N(μ), recomputed;
    the microfacet lobes are normalised already): the lobe a renderer uses without a calibration."""
    p = dict(params)
    if issubclass(LOBES[p["lobe"]], _GaussianBase):
        p.pop("scale", None)
        p["normalised"] = True
    for f, v in p.items():
        if isinstance(v, dict):
            p[f] = normalised_params(v)
    return p


@dataclasses.dataclass(frozen=True)
class LobeId:
    """A lobe's family (``to_params()["lobe"]``, a name of :data:`~jkatana.models.lobes.LOBES`) and its
    parameters, hashable by value.

    **Fields:**

    - `family`: the lobe class's name.
    - `fields`: ``((field, value), ...)`` sorted by field, numbers as Python floats, a
      :class:`~jkatana.models.lobes.Mixture`'s parts as :class:`LobeId` themselves.

    Called with a width (an array of any batch shape) it is the family width ↦ lobe that the prefilter and the
    interactive tables take (:data:`jkatana.light.prefilter.LobeFamily`): every width multiplied by ``width``.
    """

    family: str
    fields: tuple

    @classmethod
    def of(cls, params: dict) -> "LobeId":
        """The identity of a ``to_params()`` dict (inverse: :meth:`params`)."""
        p = dict(params)
        family = p.pop("lobe")
        return cls(family, tuple(sorted((k, _freeze(v)) for k, v in p.items())))

    @classmethod
    def shape_of(cls, params: dict) -> tuple[float, "LobeId"]:
        """``(width, identity)``: a lobe's primary width (that of its first part) and its identity with every
        width divided by it, so that :meth:`at_width` rebuilds the lobe at any width with the same shape (the
        same width ratios of a :class:`~jkatana.models.lobes.Mixture`'s parts, the same γ of
        :class:`~jkatana.models.lobes.GTR`)."""
        paths = _widths_of(params)
        if not paths:
            raise ValueError(f"lobe {params.get('lobe')!r} has no width parameter")
        sub = params
        for f in paths[0][0]:
            sub = sub[f]
        width = float(np.asarray(sub[paths[0][1]], np.float64))
        if not (math.isfinite(width) and width > 0):
            raise ValueError(f"lobe width must be > 0, got {width!r}")
        return width, cls.of(_map_widths(params, lambda v: float(np.asarray(v, np.float64)) / width))

    def params(self) -> dict:
        """The ``to_params()`` dict of this identity."""
        return {"lobe": self.family, **{k: v.params() if isinstance(v, LobeId) else v for k, v in self.fields}}

    def lobe(self, dtype=None) -> Lobe:
        """The lobe itself, its parameters cast to ``dtype``."""
        return lobe_from_params(self.params(), dtype)

    def at_width(self, width, dtype=None) -> Lobe:
        """The lobe with every width multiplied by ``width`` (any batch shape: per-pixel widths give per-pixel
        lobes); the other numeric parameters take the widths' batch shape and are cast to ``dtype``."""
        width = jnp.asarray(width, dtype) if dtype is not None else jnp.asarray(width)

        def other(p: dict) -> dict:
            out = {}
            for f, v in p.items():
                if isinstance(v, dict):
                    v = other(v)
                elif f != "lobe" and not isinstance(v, (bool, str)) and v is not None:
                    v = jnp.broadcast_to(jnp.asarray(v, width.dtype), width.shape)
                out[f] = v
            return out

        return lobe_from_params(_map_widths(other(self.params()), lambda v: width * v), width.dtype)

    def __call__(self, width) -> Lobe:
        return self.at_width(width)

    def normalised(self) -> "LobeId":
        """The energy-normalised form (:func:`normalised_params`): what renders without a calibration."""
        return LobeId.of(normalised_params(self.params()))

    def rendered(self, calibration: float | None) -> "LobeId":
        """The lobe a region with this identity is rendered with: :meth:`normalised` in the normalised
        convention (``calibration`` None), else the lobe as fitted (its gain s/K applied by the shader)."""
        return self.normalised() if calibration is None else self

    @property
    def name(self) -> str:
        """A stable name (a cache key's part): the identity as nested ``(family, fields)`` tuples, written out."""
        def plain(i: LobeId) -> tuple:
            return (i.family, tuple((k, plain(v) if isinstance(v, LobeId) else v) for k, v in i.fields))
        return repr(plain(self))


__all__ = ["LobeId", "normalised_params"]

"""Fitting the paper's eqs. (3)–(4) and every lobe of :mod:`jkatana.models.lobes`, with honest uncertainty.

- :func:`fit_region` / :func:`fit_table` — one region's fit (:class:`RegionFit`), any model of
  :data:`jkatana.fit._model.FIT_MODELS`, optional instrument response and robust loss.
- :mod:`jkatana.fit.uncertainty` — misfit flag, sandwich covariance, bootstrap over incidences.
- :mod:`jkatana.fit.compare` — every model on one table: per-incidence χ²/dof, AIC/BIC, leave-one-incidence-out.
- :func:`sample` — emcee posterior around a fit.
- :func:`per_incidence` — fit quality and refits per incidence angle.
- :func:`fit_pixels` — vmapped per-pixel fits for spatially varying maps.
- :func:`read_params` / :func:`write_params` — the ``jkatana-params/1`` file.
"""

from jkatana.fit._model import ModelSpec as ModelSpec, green as green, prepare as prepare
from jkatana.fit.params import Params as Params, read_params as read_params, write_params as write_params
from jkatana.fit.pixels import fit_pixels as fit_pixels
from jkatana.fit.posterior import sample as sample
from jkatana.fit.quality import per_incidence as per_incidence
from jkatana.fit.region import (
    FitData as FitData,
    RegionFit as RegionFit,
    Setup as Setup,
    fit_region as fit_region,
    fit_table as fit_table,
)

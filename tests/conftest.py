"""Test configuration: float64 on (as optimistix's tests), strict dtype promotion, jaxtyping annotations
checked at run time, hypothesis profiles.

- ``jax_numpy_dtype_promotion = "strict"``: no implicit promotion between JAX dtypes (float32 with
  float64, ints with floats), so a precision mix-up in the library is an error here, not a silent
  float64 computation (JAX's type-promotion documentation, "strict" mode).
- jaxtyping's import hook with beartype (Kidger 2022; jaxtyping's "runtime type checking" guide)
  decorates every function and dataclass of ``jkatana`` imported after it, so shapes and dtypes
  in the annotations are checked on every call the tests make. It must be installed before
  anything imports ``jkatana``.
"""

import os
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from jaxtyping import install_import_hook  # noqa: E402


def _checked_modules() -> list[str]:
    """Every module of ``jkatana`` (package ``__init__`` files hold re-exports only; the hook matches a
    package name as a prefix of all its modules, so they are not listed)."""
    root = Path(__file__).resolve().parents[1]
    return sorted(".".join(p.relative_to(root).with_suffix("").parts) for p in (root / "jkatana").rglob("*.py")
                  if p.name != "__init__.py")


# PEP 484's numeric tower: an ``int`` is a valid ``float`` (as the annotations are written)
install_import_hook(_checked_modules(), "beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))")

import jax  # noqa: E402
from hypothesis import settings  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

settings.register_profile("ci", max_examples=200, deadline=None)
settings.register_profile("dev", max_examples=60, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))

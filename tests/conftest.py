"""Test configuration: float64 on (as optimistix's tests), strict dtype promotion, jaxtyping annotations
checked at run time, hypothesis profiles, one cache folder per test run, the GL fixture.

- ``jax_numpy_dtype_promotion = "strict"``: no implicit promotion between JAX dtypes (float32 with
  float64, ints with floats), so a precision mix-up in the library is an error here, not a silent
  float64 computation (JAX's type-promotion documentation, "strict" mode).
- jaxtyping's import hook with beartype (Kidger 2022; jaxtyping's "runtime type checking" guide)
  decorates every function and dataclass of ``jkatana`` imported after it, so shapes and dtypes
  in the annotations are checked on every call the tests make. It must be installed before
  anything imports ``jkatana``.
- One cache folder per test run, shared by the pytest-xdist workers: ``$JKATANA_TEST_CACHE`` when set
  (kept afterwards, so runs or CI stages that name the same folder share it), else a new temporary
  folder removed when the run ends. It becomes ``$JKATANA_CACHE`` for the tests and the commands they
  start, so jkatana's own disk caches (prefiltered environments and Fresnel tables,
  :mod:`jkatana.light.cache`; the interactive bake and its tables, :mod:`jkatana.interactive.tables`)
  are built once per run rather than once per worker, and never read from or written to the user's
  ``~/.cache/jkatana``. Tests of the caches themselves point ``$JKATANA_CACHE`` at their own ``tmp_path``.
- JAX's persistent compilation cache in the folder ``jax`` under it (the folder ``jkatana fit`` uses under
  the same ``$JKATANA_CACHE``, :mod:`jkatana.fit.commands`): a program compiled by one
  worker, or by a command a test runs, is read back by the others instead of compiled again (programs that
  take at least 0.1 s to compile, so not each of the many tiny ones of eager operations). It holds
  compiled XLA programs keyed by the program, the options and the backend, so a hit runs the program
  a miss would compile: no result depends on it. ``JKATANA_NO_JAX_CACHE=1`` switches it off (as for
  ``jkatana fit``), e.g. to time compilation.

Both caches only save time; every test passes from an empty folder.
"""

import os
import shutil
import tempfile
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

#: environment variable naming the run's cache folder (set here for the xdist workers when not given)
TEST_CACHE_VARIABLE = "JKATANA_TEST_CACHE"
#: the folder this process created for the run and removes at its end (None: given, or a worker's)
_OWN_TEST_CACHE: Path | None = None


def _test_cache() -> Path:
    """The run's cache folder: ``$JKATANA_TEST_CACHE`` (given, or inherited by an xdist worker from the
    controller that set it), else a new temporary folder, exported so the workers started later share it."""
    global _OWN_TEST_CACHE
    given = os.environ.get(TEST_CACHE_VARIABLE)
    if given:
        path = Path(given)
        path.mkdir(parents=True, exist_ok=True)
        return path
    _OWN_TEST_CACHE = path = Path(tempfile.mkdtemp(prefix="jkatana-test-cache-"))
    os.environ[TEST_CACHE_VARIABLE] = str(path)
    return path


TEST_CACHE = _test_cache()
os.environ["JKATANA_CACHE"] = str(TEST_CACHE)

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
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
if not os.environ.get("JKATANA_NO_JAX_CACHE"):
    jax.config.update("jax_compilation_cache_dir", str(TEST_CACHE / "jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)

settings.register_profile("ci", max_examples=200, deadline=None)
settings.register_profile("dev", max_examples=60, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))


@pytest.fixture(scope="module")
def glr():
    """:mod:`jkatana.interactive.glrender` (imports pyrender on the GL platform chosen for this machine); the
    test is skipped when no OpenGL context can be made (no EGL/OSMesa packages)."""
    from jkatana.interactive.gl import GLUnavailable

    try:
        from jkatana.interactive import glrender
    except GLUnavailable as err:  # pragma: no cover - only without the Debian packages
        pytest.skip(f"no OpenGL: {err}")
    return glrender


def pytest_configure(config):
    """Stop the run with one line when the shared data folder is missing: several test modules read their maps
    from it when they are collected (:mod:`jkatana.shared` says where it is looked for)."""
    from jkatana.shared import ENV_VAR, shared_root

    data = shared_root() / "data"
    if not data.is_dir():
        pytest.exit(f"the tests need the shared data folder, and {data} is not a folder: put the shared folder "
                    f"beside the checkout (../shared) or set {ENV_VAR} to the folder that holds data/",
                    returncode=pytest.ExitCode.USAGE_ERROR)


def pytest_unconfigure(config):
    """Remove the run's temporary cache folder (only in the process that created it: the controller)."""
    if _OWN_TEST_CACHE is not None:
        shutil.rmtree(_OWN_TEST_CACHE, ignore_errors=True)

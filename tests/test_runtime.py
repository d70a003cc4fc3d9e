"""XLA's CPU thread pool as the fit-stage commands start it (:mod:`jkatana.runtime`), in child processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from jkatana.errors import InputError
from jkatana.runtime import ENV_VAR, parse_threads
from tests._scenes import cli_env

CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1

PROBE = """
import json, os, sys
from jkatana.runtime import xla_threads
set_here = xla_threads(sys.argv[1]) if sys.argv[1] != "-" else None
import jax, jax.numpy as jnp
jax.jit(lambda x: jnp.sin(x).sum())(jnp.ones(1 << 16)).block_until_ready()
mask = sorted(os.sched_getaffinity(0))
tasks = os.listdir("/proc/self/task")
names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in tasks]
masks = [sorted(os.sched_getaffinity(int(t))) for t in tasks]
again = xla_threads(1)
print(json.dumps(dict(set_here=set_here, again=again, pool=sum("Eigen" in n for n in names), mask=mask,
                      all_full=all(m == mask for m in masks))))
"""


def _probe(arg: str) -> dict:
    env = {k: v for k, v in cli_env().items() if k != "XLA_FLAGS"}
    r = subprocess.run([sys.executable, "-c", PROBE, arg], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(CORES < 2 or not sys.platform.startswith("linux"), reason="needs >= 2 cores and Linux")
def test_one_thread_pool_with_every_core_left_to_the_process():
    default = _probe("-")
    assert default["pool"] == CORES  # JAX's default: one pool thread per core (what the count measures)
    one = _probe("1")
    assert one["set_here"] is True
    assert one["pool"] == 1
    assert one["all_full"] and one["mask"] == default["mask"]  # no thread is left pinned to one core
    assert one["again"] is False  # the pool is fixed once the backend has started
    assert _probe("all")["pool"] == CORES


@pytest.mark.parametrize("value, expected", [(None, None), ("", None), ("all", None), (" ALL ", None), ("1", 1),
                                             (2, 2)])
def test_parse_threads(value, expected):
    assert parse_threads(value) == expected


@pytest.mark.parametrize("value", ["0", "-1", "two", "1.5"])
def test_bad_thread_count_names_the_variable(value):
    with pytest.raises(InputError, match=ENV_VAR):
        parse_threads(value)


def test_cli_fit_refuses_a_bad_thread_count(tmp_path):
    env = {**cli_env(), ENV_VAR: "many"}
    r = subprocess.run([sys.executable, "-m", "jkatana.cli", "fit", str(tmp_path / "missing.csv"), "-o",
                        str(tmp_path / "p.json")], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert ENV_VAR in r.stderr and "many" in r.stderr
    assert "Traceback" not in r.stderr


CACHE_PROBE = """
import collections, json, sys
from jkatana.runtime import compile_cache
folder = compile_cache()
import jax, jax.monitoring, jax.numpy as jnp
events = collections.Counter()
jax.monitoring.register_event_duration_secs_listener(lambda name, secs, **kw: events.update({name: secs}))
jax.jit(lambda x: jnp.cos(x) * 3.0 + 1.0)(jnp.ones(7)).block_until_ready()
print(json.dumps({"folder": folder, "saved": "/jax/compilation_cache/cache_retrieval_time_sec" in events}))
"""


@pytest.mark.parametrize("off", [False, True], ids=["on", "JKATANA_NO_JAX_CACHE"])
def test_compile_cache_keeps_programs_for_the_next_process(tmp_path, off):
    """Every command's compiled programs go to ``$JKATANA_CACHE/jax`` (however quick to compile), and a second
    process reads them back instead of compiling; with ``$JKATANA_NO_JAX_CACHE`` nothing is kept."""
    env = cli_env()
    env["JKATANA_CACHE"] = str(tmp_path)
    for name in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "JKATANA_NO_JAX_CACHE"):
        env.pop(name, None)
    if off:
        env["JKATANA_NO_JAX_CACHE"] = "1"
    runs = [json.loads(subprocess.run([sys.executable, "-c", CACHE_PROBE], capture_output=True, text=True,
                                      env=env, check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    if off:
        assert runs[0]["folder"] is None and not (tmp_path / "jax").exists() and not runs[1]["saved"]
    else:
        assert runs[0]["folder"] == str(tmp_path / "jax") and any((tmp_path / "jax").iterdir())
        assert not runs[0]["saved"] and runs[1]["saved"]


@pytest.mark.parametrize("own", [False, True], ids=["default", "JAX_COMPILATION_CACHE_DIR"])
def test_the_command_line_sets_the_compile_cache_before_jax_starts(tmp_path, own):
    """``jkatana`` points JAX at the cache before the command's module imports it (so its worker processes
    inherit the folder too), keeping every program however quick to compile; a folder the caller names in
    ``JAX_COMPILATION_CACHE_DIR`` is used as it is, with the same setting."""
    env = cli_env()
    env["JKATANA_CACHE"] = str(tmp_path)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.pop("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", None)
    folder = tmp_path / ("own" if own else "jax")
    if own:
        env["JAX_COMPILATION_CACHE_DIR"] = str(folder)
    code = ("from jkatana.cli import main; main(['light', 'cache']); import jax; "
            "print(jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip().splitlines()[-1] == f"{folder} 0.0"


def test_render_devices_reach_xla():
    """Building ``jkatana render``'s and ``demo``'s parser leaves JAX unimported, so the host devices the command
    then asks for (``--devices``, default one: :func:`jkatana.render.commands._setup_devices`) are the
    ones XLA starts with."""
    env = cli_env()
    env.pop("XLA_FLAGS", None)
    code = ("import sys\nfrom jkatana.cli import build_parser\nbuild_parser('render'); build_parser('demo')\n"
            "print('jax' in sys.modules)\nfrom jkatana.render.commands import _setup_devices\n_setup_devices(3)\n"
            "import jax\nprint(jax.device_count())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split() == ["False", "3"], out.stdout

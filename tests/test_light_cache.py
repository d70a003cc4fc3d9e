"""Environments loaded once: content-keyed cache of the radiance, the renderer's environment, the Fresnel table."""

from __future__ import annotations

import numpy as np
import pytest

from jkatana.io.exr import write_exr
from jkatana.light import cache


def _scene(tmp_path, env_path, rotation=0.0, mode="reference"):
    from jkatana.render.scenefile import scene_from_dict

    return scene_from_dict({
        "geometry": {"sphere": {"center": [0.0, 0.0, 0.0], "radius": 1.0}},
        "material": {"w": 1.0, "mu0": 0.05, "mu1": 0.2, "optical_constants": "Fe-Johnson"},
        "environment": {"type": "exr", "path": str(env_path), "rotation_deg": rotation},
        "camera": {"type": "orbit", "target": [0.0, 0.0, 0.0], "distance": 4.0, "azimuth_deg": 0.0,
                   "elevation_deg": 0.0, "fov_deg": 30.0, "resolution": [16, 12]},
        "spectral": {"start": 400.0, "stop": 700.0, "step": 20.0},
        "render": {"mode": mode, "samples": 4},
    }, tmp_path / "scene.toml")


def _env_file(tmp_path, name="env.exr", bright=(3, 20)):
    rgb = np.full((16, 32, 3), 0.5, np.float32)
    rgb[bright] = (40.0, 30.0, 20.0)
    return write_exr(tmp_path / name, {c: rgb[..., k] for k, c in enumerate("RGB")})


def test_tree_round_trip_keeps_every_leaf(tmp_path):
    import jax
    import jax.numpy as jnp

    from jkatana.render.environment import build_environment

    from jkatana.spectral.grid import WavelengthGrid

    grid = WavelengthGrid(400.0, 700.0, 20.0)
    rad = np.random.default_rng(0).random((8, 16, grid.size)).astype(np.float32) + 0.1
    env = build_environment(rad, prefilter_mus=(0.05, 0.2), prefilter_resolution=16, grid=grid)
    back = cache.load_tree(cache.save_tree(tmp_path / "e", env))
    a, b = jax.tree_util.tree_flatten(env), jax.tree_util.tree_flatten(back)
    assert a[1] == b[1]  # same structure, classes and static fields
    for x, y in zip(a[0], b[0]):
        assert type(x) is type(jnp.asarray(y)) or type(x) is type(y)
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_only_jkatana_classes_are_rebuilt(tmp_path):
    import dataclasses
    import json

    @dataclasses.dataclass
    class Foreign:
        x: int = 1

    with pytest.raises(TypeError):
        cache.save_tree(tmp_path / "f", Foreign())
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "tree.json").write_text(json.dumps({"class": "os:system", "fields": {}}))
    with pytest.raises(ValueError, match="refusing"):
        cache.load_tree(bad)


def test_second_prepare_reads_the_cache_and_renders_the_same(tmp_path, monkeypatch):
    from jkatana.render import environment, renderer

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    path = _env_file(tmp_path)
    first = renderer.prepare(_scene(tmp_path, path))
    f1 = renderer.render_view(first)

    def refuse(*a, **k):
        raise AssertionError("rebuilt although cached")

    monkeypatch.setattr(environment, "build_environment", refuse)
    monkeypatch.setattr(renderer, "build_environment", refuse)
    monkeypatch.setattr(renderer, "_build_radiance", refuse)
    monkeypatch.setattr(renderer, "fresnel_table", refuse)
    second = renderer.prepare(_scene(tmp_path, path))
    f2 = renderer.render_view(second)
    np.testing.assert_array_equal(f1.xyz, f2.xyz)
    # the rotation is applied after the cache: same entry, turned light
    turned = renderer.prepare(_scene(tmp_path, path, rotation=90.0))
    np.testing.assert_allclose(np.asarray(turned.env.rotation), renderer.rotation_y(90.0), atol=1e-6)
    # new content → new key → built again (and refused here)
    other = _env_file(tmp_path, "other.exr", bright=(5, 3))
    with pytest.raises(AssertionError, match="rebuilt"):
        renderer.prepare(_scene(tmp_path, other))


def test_only_a_sampling_mode_builds_the_sampling_tables(tmp_path, monkeypatch):
    """A mode that never samples the map (prefiltered, paper) gets an environment without sampling tables, in
    a cache entry of its own; every other array is the one the tables' build gives, and so is the frame."""
    import dataclasses

    import jax

    from jkatana.render import renderer
    from jkatana.render.integrators import integrator_for

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    path = _env_file(tmp_path)
    assert renderer.prepare(_scene(tmp_path, path)).env.sampler is not None          # reference: MIS
    prep = renderer.prepare(_scene(tmp_path, path, mode="prefiltered"))
    assert prep.env.sampler is None and not integrator_for("prefiltered").sampled
    entries = sorted(p.name for p in (tmp_path / "cache").rglob("environment-*"))
    sampled = dataclasses.replace(integrator_for("prefiltered"), sampled=True)
    env, *_ = renderer._environment(prep.scene, prep.grid, prep.dtype, sampled, prep.maps,
                                    {"hiraji": None, "hamon": None}, rank=None, env_radiance=None, split_sun=None,
                                    max_memory=None)
    assert env.sampler is not None
    assert len(sorted(p.name for p in (tmp_path / "cache").rglob("environment-*"))) == len(entries) + 1
    leaves = jax.tree_util.tree_leaves(dataclasses.replace(env, sampler=None))
    assert len(leaves) == len(jax.tree_util.tree_leaves(prep.env))
    for a, b in zip(leaves, jax.tree_util.tree_leaves(prep.env)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(renderer.render_view(dataclasses.replace(prep, env=env)).xyz,
                                  renderer.render_view(prep).xyz)


def test_key_follows_content_and_method(tmp_path):
    from jkatana.render.scene import EnvironmentSpec
    from jkatana.spectral.grid import WavelengthGrid

    path = _env_file(tmp_path)
    grid = WavelengthGrid(400.0, 700.0, 20.0)
    e = EnvironmentSpec(type="exr", path=path, upsampling="Jakob 2019", scale=1.0, colourspace="sRGB")
    k0 = cache.radiance_key(e, grid)
    assert k0 == cache.radiance_key(e, grid)
    assert k0 != cache.radiance_key(EnvironmentSpec(type="exr", path=path, upsampling="Smits 1999", scale=1.0,
                                                colourspace="sRGB"), grid)
    assert k0 != cache.radiance_key(e, WavelengthGrid(400.0, 700.0, 10.0))
    _env_file(tmp_path, bright=(4, 4))  # same name, new bytes
    assert k0 != cache.radiance_key(e, grid)
    assert cache.environment_key(k0, rank=None, prefilter_mus=(), prefilter_resolution=128, dtype=np.float32) != \
        cache.environment_key(k0, rank=3, prefilter_mus=(), prefilter_resolution=128, dtype=np.float32)


def test_light_prefilter_fills_the_cache_a_render_then_reads(tmp_path, monkeypatch, capsys):
    """`jkatana light prefilter SCENE` builds the scene's environment into the cache; `prepare` then hits it."""
    from jkatana.cli import main
    from jkatana.render.renderer import prepare
    from jkatana.render.scenefile import scene_to_toml

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    scene = _scene(tmp_path, _env_file(tmp_path), mode="prefiltered")
    (tmp_path / "scene.toml").write_text(scene_to_toml(scene))
    assert main(["light", "prefilter", str(tmp_path / "scene.toml")]) == 0
    assert "cached" in capsys.readouterr().out
    made = sorted(p.name for p in cache.cache_root().rglob("*") if p.is_file())
    assert made, "nothing was cached"
    prepare(scene)  # a render of the scene: reads, writes nothing new
    assert sorted(p.name for p in cache.cache_root().rglob("*") if p.is_file()) == made


# ----------------------------------------------------------------------------- budget and eviction


def _entry(base, sub, name, size, when):
    """A cache entry of ``size`` bytes last used at POSIX time ``when`` (a folder for ``environment-*``)."""
    import os

    folder = base / sub
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    if name.startswith("environment-"):
        p.mkdir()
        (p / "tree.json").write_text("{}")
        (p / "a0.npy").write_bytes(b"\0" * (size - 2))
    else:
        p.write_bytes(b"\0" * size)
    os.utime(p, (when, when))
    return p


def _four(base):
    return [_entry(base, "environments", "radiance-a.npy", 1000, 100.0),
            _entry(base, "interactive", "baked-b.npz", 1000, 200.0),
            _entry(base, "environments", "environment-c", 1000, 300.0),
            _entry(base, "interactive", "taps-d.npz", 1000, 400.0)]


def test_eviction_removes_the_least_recently_used_entries_down_to_the_budget(tmp_path):
    a, b, c, d = _four(tmp_path)
    (tmp_path / "environments" / ".radiance-x.1234.npy").write_bytes(b"\0" * 5000)  # a write in progress
    listed = cache.entries(tmp_path)
    assert [e.path for e in listed] == [a, b, c, d] and sum(e.size for e in listed) == 4000
    assert cache.evict(tmp_path, budget=2500) == [a, b]
    assert not a.exists() and not b.exists() and c.is_dir() and d.exists()
    assert (tmp_path / "environments" / ".radiance-x.1234.npy").exists()       # temporaries are not entries
    assert cache.evict(tmp_path, budget=2000) == []                             # within the budget: nothing
    assert cache.evict(tmp_path, budget=0) == [c, d]
    assert not any(p.name.startswith(".evicted") for p in (tmp_path / "environments").iterdir())


def test_an_entry_in_use_is_never_evicted(tmp_path):
    a, b, c, d = _four(tmp_path)
    assert cache.acquire(a) and cache.acquire(c)
    try:
        assert a.stat().st_mtime > 400.0                 # acquiring is a use: now the most recent
        assert cache.evict(tmp_path, budget=0) == [b, d]
        assert a.exists() and c.is_dir()
        removed, kept = cache.clear(tmp_path)
        assert removed == [] and sorted(kept) == sorted([a, c])
    finally:
        cache.release(a)
        cache.release(c)
    assert sorted(cache.clear(tmp_path)[0]) == sorted([a, c])
    assert not cache.acquire(a)                          # gone: the reader builds it again


def test_an_entry_held_by_another_process_is_not_evicted(tmp_path):
    import os
    import subprocess
    import sys

    a, b, c, d = _four(tmp_path)
    code = ("import sys; from jkatana.light import cache; assert cache.acquire(sys.argv[1]); print('held', flush=True); "
            "sys.stdin.read()")
    proc = subprocess.Popen([sys.executable, "-c", code, str(c)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=dict(os.environ))
    try:
        assert proc.stdout.readline().strip() == "held"
        assert cache.evict(tmp_path, budget=0) == [a, b, d]
        assert c.is_dir()
    finally:
        proc.communicate("", timeout=60)
    assert cache.evict(tmp_path, budget=0) == [c]       # released when that process ended


def test_reading_an_entry_marks_it_used_and_a_write_evicts_older_ones(tmp_path, monkeypatch):
    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path))
    a, b, c, d = _four(tmp_path)
    monkeypatch.setenv(cache.BUDGET_VARIABLE, "0.0035")          # 3500 bytes: less than the four
    np.save(tmp_path / "environments" / "radiance-k.npy", np.zeros(8, np.float32))   # 160 bytes, oldest
    import os

    os.utime(tmp_path / "environments" / "radiance-k.npy", (50.0, 50.0))
    old = cache.cached_radiance("k", lambda: (_ for _ in ()).throw(AssertionError("rebuilt")))
    assert old.shape == (8,)                                     # read from the cache: now the most recent
    new = cache.cached_radiance("n", lambda: np.ones((16, 16), np.float32))        # 1152 bytes written
    assert new.shape == (16, 16)
    gone = {p.name for p in (a, b, c, d) if not p.exists()}
    assert gone == {"radiance-a.npy", "baked-b.npz"}, gone       # the two least recently used went
    assert (tmp_path / "environments" / "radiance-k.npy").exists()
    assert (tmp_path / "environments" / "radiance-n.npy").exists()
    # an entry larger than the whole budget stays while its writer holds it
    monkeypatch.setenv(cache.BUDGET_VARIABLE, "0")
    cache.cached_radiance("big", lambda: np.ones((64, 64), np.float32))
    assert (tmp_path / "environments" / "radiance-big.npy").exists()


def test_budget_comes_from_the_environment(monkeypatch):
    from jkatana.errors import InputError

    monkeypatch.delenv(cache.BUDGET_VARIABLE, raising=False)
    assert cache.cache_budget() == int(cache.DEFAULT_BUDGET_MB * 1e6)
    monkeypatch.setenv(cache.BUDGET_VARIABLE, "1.5")
    assert cache.cache_budget() == 1_500_000
    for bad in ("lots", "-1", "nan", "inf"):
        monkeypatch.setenv(cache.BUDGET_VARIABLE, bad)
        with pytest.raises(InputError, match=cache.BUDGET_VARIABLE):
            cache.cache_budget()


def test_bake_cache_shares_the_budget(tmp_path, monkeypatch):
    """The interactive bake's entries are listed, touched on read and evicted with the environments'."""
    from jkatana.interactive import tables

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path))
    old = _entry(tmp_path, "environments", "radiance-old.npy", 1000, 100.0)
    monkeypatch.setenv(cache.BUDGET_VARIABLE, "0.0001")
    path = tables.cache_folder() / "material-x.npz"
    tables.save_entry(path, None, a=np.zeros(4))
    assert path.exists() and not old.exists()
    import os

    os.utime(path, (10.0, 10.0))
    assert tables.load_entry(path, lambda z: z["a"].shape) == (4,)
    assert path.stat().st_mtime > 10.0


def test_cli_lists_and_clears_the_cache(tmp_path, monkeypatch, capsys):
    from jkatana.cli import main

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path))
    _four(tmp_path)
    assert main(["light", "cache"]) == 0
    out = capsys.readouterr().out
    assert "4 entries, 0.0 MB" in out and "interactive/taps-d.npz" in out and "environments/environment-c" in out
    assert main(["light", "cache", "--clear"]) == 0
    assert "removed 4 entries" in capsys.readouterr().out
    assert cache.entries(tmp_path) == []

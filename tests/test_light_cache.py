"""Environments loaded once: content-keyed cache of the radiance, the renderer's environment, the Fresnel table."""

from __future__ import annotations

import numpy as np
import pytest

from jkatana.io.exr import write_exr
from jkatana.light import cache


def _scene(tmp_path, env_path, rotation=0.0, mode="reference"):
    from jkatana.render.scene import scene_from_dict

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

    from jkatana.render.shading import build_environment

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
    from jkatana.render import renderer, shading

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    path = _env_file(tmp_path)
    first = renderer.prepare(_scene(tmp_path, path))
    f1 = renderer.render_view(first)

    def refuse(*a, **k):
        raise AssertionError("rebuilt although cached")

    monkeypatch.setattr(shading, "build_environment", refuse)
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


def test_key_follows_content_and_method(tmp_path):
    from jkatana.render.scene import Environment
    from jkatana.spectral.grid import WavelengthGrid

    path = _env_file(tmp_path)
    grid = WavelengthGrid(400.0, 700.0, 20.0)
    e = Environment(type="exr", path=path, upsampling="Jakob 2019", scale=1.0, colourspace="sRGB")
    k0 = cache.radiance_key(e, grid)
    assert k0 == cache.radiance_key(e, grid)
    assert k0 != cache.radiance_key(Environment(type="exr", path=path, upsampling="Smits 1999", scale=1.0,
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

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    scene = _scene(tmp_path, _env_file(tmp_path), mode="prefiltered")
    (tmp_path / "scene.toml").write_text(scene.to_toml_text())
    assert main(["light", "prefilter", str(tmp_path / "scene.toml")]) == 0
    assert "cached" in capsys.readouterr().out
    made = sorted(p.name for p in cache.cache_root().rglob("*") if p.is_file())
    assert made, "nothing was cached"
    prepare(scene)  # a render of the scene: reads, writes nothing new
    assert sorted(p.name for p in cache.cache_root().rglob("*") if p.is_file()) == made

"""Maps read in row blocks (:mod:`jkatana.light.streaming`, :mod:`jkatana.render.streamed`): the chromaticity
table against the per-texel upsampling, the spectral EXR's row blocks against its whole read, and the streamed
environment of a small map (forced by a tiny budget) against the full path, within the error it measures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jkatana.spectral import DEFAULT_GRID, WavelengthGrid

HDR_1K = Path(__file__).resolve().parents[2] / "shared" / "data" / "envmaps" / "pedestrian_overpass_1k.hdr"


def _rgb_map(H=64, W=128, sun=True):
    """The shared 1k HDR box-filtered to ``H × W``, with a one-texel sun of 2·10⁴ times the sky."""
    import OpenImageIO as oiio

    px = np.asarray(oiio.ImageBuf(str(HDR_1K)).get_pixels(oiio.FLOAT))[..., :3]
    f = px.shape[0] // H
    rgb = px.reshape(H, f, W, f, 3).mean(axis=(1, 3)).astype(np.float32)
    if sun:
        rgb[H // 4, W // 3] = np.array([1.0, 0.9, 0.7], np.float32) * 2e4 * rgb.mean()
    return rgb


def _write_hdr(path: Path, rgb: np.ndarray) -> Path:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(np.ascontiguousarray(rgb))
    assert buf.write(str(path)), buf.geterror()
    return path


#: The table's measured relative error on random colours (saturated ones included, the hardest): the
#: linear methods to rounding, Smits's piecewise-linear one nearly, the sigmoid spectra to ~1e-3.
TABLE_ERROR = {"Jakob 2019": 1.2e-3, "Jakob 2019 LUT": 4e-4, "Mallett 2019": 1e-6, "Smits 1999": 2e-5,
               "Flat": 1e-6}


@pytest.mark.parametrize("method", sorted(TABLE_ERROR))
def test_chromaticity_table_matches_the_per_texel_upsampling(method):
    """Every method is homogeneous of degree one: the table's value times the largest channel reproduces the
    upsampled spectrum (projected) to the table's interpolation error, and to rounding at its nodes."""
    from jkatana.light.upsampling import chromaticity_table, rgb_to_spectrum, table_lookup

    rng = np.random.default_rng(3)
    rgb = (rng.random((4000, 3)) ** 2 * rng.lognormal(0, 2, (4000, 1))).astype(np.float32)
    P = np.linalg.qr(rng.standard_normal((DEFAULT_GRID.size, 5)))[0]
    exact = rgb_to_spectrum(rgb, method, DEFAULT_GRID).astype(np.float64) @ P
    approx = table_lookup(chromaticity_table(lambda S: S @ P, method, DEFAULT_GRID), rgb)
    assert np.linalg.norm(approx - exact) / np.linalg.norm(exact) < TABLE_ERROR[method]
    nodes = np.array([[1.0, 0.25, 0.5], [0.0, 3.0, 1.5], [0.0, 0.0, 0.0]], np.float32)  # on table nodes
    exact = rgb_to_spectrum(nodes, method, DEFAULT_GRID).astype(np.float64) @ P
    got = table_lookup(chromaticity_table(lambda S: S @ P, method, DEFAULT_GRID), nodes)
    assert np.allclose(got, exact, rtol=2e-5, atol=1e-6)


@pytest.mark.parametrize("grid", [DEFAULT_GRID, WavelengthGrid(400.0, 700.0, 10.0)], ids=["same", "resampled"])
def test_spectral_exr_row_blocks_equal_the_whole_read(tmp_path, grid):
    from jkatana.light.spectral_exr import SpectralRows, read_spectral_exr, write_spectral_exr

    L = np.random.default_rng(1).random((13, 26, DEFAULT_GRID.size)).astype(np.float32)
    path = write_spectral_exr(tmp_path / "s.exr", L, DEFAULT_GRID)
    whole = read_spectral_exr(path, grid)
    rows = SpectralRows(path, grid)
    assert (rows.height, rows.width) == (13, 26)
    blocks = np.concatenate([rows.rows(0, 4), rows.rows(4, 5), rows.rows(5, 13)])
    np.testing.assert_array_equal(blocks, whole)


def _compare(full, streamed, resid):
    """The streamed environment against the full one: spectra, levels and caps within the measured error."""
    basis = np.asarray(streamed[0].basis, np.float64)
    f, s = full[0], streamed[0]
    got = np.asarray(s.channels, np.float64) @ basis
    ref = np.asarray(f.channels, np.float64)
    assert 0 < resid < 2e-3
    assert np.linalg.norm(got - ref) / np.linalg.norm(ref) < 3 * resid
    for a, b in zip(f.prefiltered, s.prefiltered):
        a = np.asarray(a, np.float64)
        assert np.linalg.norm(np.asarray(b, np.float64) @ basis - a) / np.linalg.norm(a) < 3 * resid
    assert (f.caps is None) == (s.caps is None)
    if f.caps is not None:
        np.testing.assert_allclose(np.asarray(s.caps.direction), np.asarray(f.caps.direction), atol=1e-6)
        np.testing.assert_allclose(np.asarray(s.caps.radius), np.asarray(f.caps.radius), rtol=1e-5)
        a = np.asarray(f.caps.channels, np.float64)
        assert np.linalg.norm(np.asarray(s.caps.channels, np.float64) @ basis - a) / np.linalg.norm(a) < 1e-3
    pa, pb = np.asarray(f.sampler.texel_pdf), np.asarray(s.sampler.texel_pdf)
    assert np.abs(pa - pb).max() < 3 * resid * pa.max()


@pytest.mark.parametrize("kind", ["hdr", "spectral-exr"])
def test_streamed_environment_equals_the_full_one_within_its_measured_error(tmp_path, kind):
    from jkatana.light.envmap import load_envmap
    from jkatana.light.spectral_exr import write_spectral_exr
    from jkatana.light.streaming import row_source
    from jkatana.light.upsampling import rgb_to_spectrum
    from jkatana.render.environment import build_environment
    from jkatana.render.streamed import build_streamed_environment

    rgb = _rgb_map()
    if kind == "hdr":
        path = _write_hdr(tmp_path / "m.hdr", rgb)
    else:
        path = write_spectral_exr(tmp_path / "m.exr", rgb_to_spectrum(rgb, "Jakob 2019", DEFAULT_GRID), DEFAULT_GRID)
    L = np.asarray(load_envmap(path, DEFAULT_GRID).radiance)
    kw = dict(prefilter_mus=(0.02, 0.1), split_sun=True)
    full = build_environment(L, grid=DEFAULT_GRID, **kw)
    streamed = build_streamed_environment(row_source(path, DEFAULT_GRID), **kw)
    assert streamed[1] is True and streamed[0].caps is not None
    _compare(full, streamed, streamed[2])


@pytest.mark.slow
def test_tiny_budget_streams_the_map_and_the_frame_stays_within_the_error(tmp_path, monkeypatch):
    """``prepare`` under a budget the whole spectra exceed takes the streamed path (factored, its residual
    reported); the prefiltered frame equals the full path's to the measured error; under the machine's
    budget the same scene is prepared as before (not factored)."""
    import jkatana.render.memory as memory
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scenefile import scene_from_dict

    monkeypatch.setenv("JKATANA_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(memory, "STREAM_BLOCK_BYTES", 0.0)
    path = _write_hdr(tmp_path / "m.hdr", _rgb_map())
    scene = scene_from_dict({"environment": {"type": "hdr", "path": str(path)},
                             "camera": {"resolution": [24, 18]}, "render": {"mode": "prefiltered"}})
    full_est = memory.full_bytes(scene.environment, scene.spectral.grid.size)
    stream_est = memory.streamed_bytes(scene.environment)
    assert stream_est < full_est
    budget = int(memory.BASE_BYTES + (full_est + stream_est) / 2)
    a = prepare(scene)
    b = prepare(scene, max_memory=budget)
    assert not a.env_info["factored"] and b.env_info["factored"]
    resid = b.env_info["rank_residual"]
    assert 0 < resid < 2e-3
    fa, fb = np.asarray(render_view(a, seed=3).xyz), np.asarray(render_view(b, seed=3).xyz)
    assert np.linalg.norm(fb - fa) / np.linalg.norm(fa) < 3 * resid


def test_streamed_bake_levels_equal_the_full_bake(tmp_path):
    """``view``'s bake of a map read in row blocks: the same levels (to the chromaticity table's error), caps
    and tables as the bake of its whole spectra; the texture the shaders read is at the finest level's size."""
    from jkatana.interactive.bake import _bake, _bake_rows
    from jkatana.interactive.levels import MU_LEVELS
    from jkatana.interactive.lobe_tables import PAPER_LOBES
    from jkatana.light.envmap import load_envmap
    from jkatana.light.streaming import row_source
    from jkatana.models import Conductor

    path = _write_hdr(tmp_path / "m.hdr", _rgb_map())
    conductor = Conductor.from_table("Fe-Johnson", DEFAULT_GRID)
    kw = dict(conductor=conductor, rank=3, mus=MU_LEVELS, colourspace="sRGB", transfer=None,
              cache_dir=None, split_sun=True, lobes=PAPER_LOBES)
    full, lv_full = _bake(np.asarray(load_envmap(path, DEFAULT_GRID).radiance, np.float64), DEFAULT_GRID, **kw)
    rows, lv_rows = _bake_rows(row_source(path, DEFAULT_GRID), **kw)
    assert full.n_caps == rows.n_caps == 1
    np.testing.assert_allclose(rows.cap_dir, full.cap_dir, atol=1e-6)
    np.testing.assert_allclose(rows.cap_q, full.cap_q, rtol=1e-5)
    for a, b in zip(lv_full, lv_rows):
        assert a.shape == b.shape
        assert np.linalg.norm(b - a) / np.linalg.norm(a) < 1e-3
    np.testing.assert_array_equal(rows.taps, full.taps)
    assert rows.env.shape[2:4] == lv_rows[0].shape[:2] and rows.env.shape[:2] == full.env.shape[:2]


def test_project_all_is_the_row_blocks_stitched(tmp_path, monkeypatch):
    """One pass of row blocks (several here) cut into the callers' arrays equals the whole map's projection;
    a 0 in ``splits`` gives a 2-D array; splits that do not cover the projection are refused."""
    import jkatana.light.streaming as streaming

    path = _write_hdr(tmp_path / "m.hdr", _rgb_map(32, 64))
    source = streaming.row_source(path, DEFAULT_GRID)
    P = np.random.default_rng(1).standard_normal((DEFAULT_GRID.size, 4))
    whole = source.project(0, source.height, P)
    monkeypatch.setattr(streaming, "BLOCK_TEXELS", 5 * 64)        # 5 rows a block: 7 blocks, the last short
    assert source.block_rows() == 5
    a, y, z = source.project_all(P, (2, 0, 0))
    assert a.shape == (32, 64, 2) and y.shape == z.shape == (32, 64)
    np.testing.assert_array_equal(a, whole[..., :2])
    np.testing.assert_array_equal(y, whole[..., 2])
    np.testing.assert_array_equal(z, whole[..., 3])
    with pytest.raises(ValueError, match="do not cover"):
        source.project_all(P, (2, 0))


def test_view_streams_every_map_file_and_render_only_those_too_large():
    """``view``'s bake reads projections only: every map file takes the row route for it, whatever its size;
    ``render`` keeps a map that fits on the whole-spectra path (its frames unchanged); the built-in sky has no
    file to stream."""
    from jkatana.render.memory import environment_route
    from jkatana.render.scenefile import scene_from_dict

    hdr = scene_from_dict({"environment": {"type": "hdr", "path": str(HDR_1K)}}).environment
    sky = scene_from_dict({}).environment
    assert environment_route(hdr, 61, interactive=True) == "streamed"
    assert environment_route(hdr, 61) == "full"
    assert environment_route(hdr, 61, max_memory=1 << 30) == "streamed"
    assert environment_route(sky, 61, interactive=True) == environment_route(sky, 61) == "full"

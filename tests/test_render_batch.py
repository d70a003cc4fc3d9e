"""Batch rendering: an interrupted batch resumes without redoing or corrupting frames; Dask path."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from tests._scenes import CLI, cli_env, sphere_scene


def _frames(d: Path):
    return sorted(p for p in d.glob("*.png") if not p.name.startswith("."))


@pytest.mark.slow
def test_killed_batch_resumes_without_redoing_or_corrupting(tmp_path):
    from PIL import Image

    from jkatana.io.exr import read_exr

    scene = tmp_path / "scene.toml"
    scene.write_text(sphere_scene(64, 48, 96))
    out = tmp_path / "out"
    n_views = 10
    proc = subprocess.Popen(CLI + ["render", str(scene), "--views", str(n_views)], cwd=tmp_path, env=cli_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + 240
    try:
        while time.time() < deadline and proc.poll() is None:
            if len(_frames(out)) >= 1:
                break
            time.sleep(0.02)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # no chance to clean up
        proc.wait()
    done = _frames(out)
    assert 1 <= len(done) < n_views, f"kill did not land mid-batch ({len(done)} frames)"
    before = {p.name: p.stat().st_mtime_ns for p in done}
    for p in done:  # every finished frame is complete and readable
        Image.open(p).load()
        ch, _ = read_exr(p.with_suffix(".exr"))
        assert np.isfinite(ch["Y"]).all()
    r = subprocess.run(CLI + ["render", str(scene), "--views", str(n_views)], cwd=tmp_path, env=cli_env(),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    after = _frames(out)
    assert len(after) == n_views
    for name, mtime in before.items():  # not redone
        assert (out / name).stat().st_mtime_ns == mtime
    assert f"{len(done)} skipped" in r.stdout and f"{n_views - len(done)} rendered" in r.stdout
    for p in after:
        Image.open(p).load()
        ch, hdr = read_exr(p.with_suffix(".exr"))
        assert ch["X"].shape == (48, 64) and hdr["jkatana_samples"] == 96


def test_cli_reports_bad_scene_in_one_line(tmp_path):
    scene = tmp_path / "bad.toml"
    scene.write_text("[camera]\nresolution = [0, 10]\n")
    r = subprocess.run(CLI + ["render", str(scene)], capture_output=True, text=True, env=cli_env(), timeout=120)
    assert r.returncode == 2
    lines = [l for l in r.stderr.strip().splitlines() if "error" in l]
    assert len(lines) == 1 and "camera.resolution" in lines[0] and str(scene) in lines[0]


@pytest.mark.slow
def test_dask_local_cluster_batch(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(sphere_scene(24, 18, 2))
    r = subprocess.run(CLI + ["render", str(scene), "--views", "2", "--lights", "2", "--dask", "--workers", "1"],
                       cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(_frames(tmp_path / "out")) == 4
    assert "4 rendered" in r.stdout

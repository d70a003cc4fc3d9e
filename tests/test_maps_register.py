"""``jkatana map PHOTO... --mesh``: bad input refused in one line (exit 2, no map written), and the pieces of
the registration that need no renderer. The accuracy tests on Mitsuba photos are in
``test_maps_register_mitsuba.py``.

The photos here are ray cast through trimesh by :func:`_raycast_photo` (a pinhole camera, each pixel the
relative brightness of the texel its ray hits: dark hiraji, bright hamon, a flat backdrop): enough to make
a registrable blade for the error paths.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from jkatana.io.exr import write_exr


def _raycast_photo(mesh, w, shot, *, backdrop: float = 0.2) -> np.ndarray:
    from validation.photos import camera_frame, _spec

    from jkatana.maps import ReflectanceMap

    origin, target, up = camera_frame(_spec(mesh), shot)
    W, H = shot.width, shot.height
    fwd = (target - origin) / np.linalg.norm(target - origin)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    f = (W / 2) / math.tan(math.atan(0.5 * shot.span_m / shot.distance_m))
    xs, ys = np.meshgrid(np.arange(W) + 0.5 - W / 2, np.arange(H) + 0.5 - H / 2)
    d = fwd + xs.ravel()[:, None] / f * right + ys.ravel()[:, None] / f * down
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(origin, d.shape)
    loc, ray, tri = mesh.ray.intersects_location(o, d, multiple_hits=False)
    import trimesh

    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc)
    uv = np.einsum("nk,nkd->nd", bary, np.asarray(mesh.visual.uv)[mesh.faces[tri]])
    m = ReflectanceMap.uniform(w.shape)
    m.w[:] = w
    wv = m.sample(uv[:, 0], uv[:, 1])["w"]
    img = np.full(H * W, backdrop)
    img[ray] = backdrop * (0.1 * wv + 5.0 * (1 - wv))
    rng = np.random.default_rng(shot.seed)
    return np.clip(img.reshape(H, W) + rng.normal(0, 0.002, (H, W)), 0, None)


def _exr(path, y):
    write_exr(path, {"R": y, "G": y, "B": y})
    return str(path)


@pytest.fixture(scope="module")
def blade_ply(tmp_path_factory):
    from jkatana.shape.katana import default_blade, export_blade

    path = tmp_path_factory.mktemp("mesh") / "blade.ply"
    export_blade(default_blade(), path)
    return path


def _fails(capsys, args, *words):
    from jkatana.cli import main

    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    err = [e for e in err if "registering photos" not in e]  # the progress bar's own lines
    assert len(err) == 1, err
    for word in words:
        assert word in err[0], err[0]
    return err[0]


def test_photo_without_a_blade(tmp_path, capsys, blade_ply):
    yy, xx = np.mgrid[0:300:1, 0:900:1]
    y = 0.2 * (1 + 0.3 * xx / 900) + np.random.default_rng(0).normal(0, 0.002, xx.shape)
    photo = _exr(tmp_path / "wall.exr", y)
    out = tmp_path / "map.exr"
    _fails(capsys, ["map", photo, "--mesh", str(blade_ply), "-o", str(out)], "wall.exr", "no blade-like object")
    assert not out.exists()


def test_mesh_without_blade_uvs(tmp_path, capsys):
    import trimesh

    from jkatana.shape.katana import default_blade

    b = default_blade()
    bare = tmp_path / "bare.ply"
    bare.write_bytes(trimesh.Trimesh(b.vertices, b.faces, process=False).export(file_type="ply"))
    swapped = tmp_path / "swapped.ply"
    s = b.copy()
    s.visual = trimesh.visual.TextureVisuals(uv=np.asarray(b.visual.uv)[:, ::-1])
    swapped.write_bytes(s.export(file_type="ply"))
    photo = _exr(tmp_path / "p.exr", np.full((50, 200), 0.2))
    out = tmp_path / "map.exr"
    for mesh in (bare, swapped):
        _fails(capsys, ["map", photo, "--mesh", str(mesh), "-o", str(out)], mesh.name, "blade UVs")
    assert not out.exists()


def test_registration_that_does_not_converge(tmp_path, capsys, blade_ply):
    """A straight bar, dark above and bright below, is blade-like but no view of the curved blade fits it."""
    y = np.full((500, 1500), 0.2)
    y[230:255, 200:1300] = 0.01
    y[255:275, 200:1300] = 1.0
    photo = _exr(tmp_path / "bar.exr", y)
    out = tmp_path / "map.exr"
    _fails(capsys, ["map", photo, "--mesh", str(blade_ply), "-o", str(out)], "bar.exr", "did not converge")
    assert not out.exists()


@pytest.mark.slow  # four ray-cast photos and two registrations: the slow stage
def test_photos_of_different_blades(tmp_path, capsys, blade_ply):
    from validation.photos import Shot, choji_map

    from jkatana.maps import default_map
    from jkatana.shape.katana import KatanaSpec, build_blade, default_blade

    w = default_map((128, 512)).w
    shots = [Shot(target_u=0.3, span_m=0.5, width=1200, height=500, tilt_deg=8, roll_deg=3, distance_m=0.8),
             Shot(target_u=0.7, span_m=0.5, width=1200, height=500, tilt_deg=6, roll_deg=-2, distance_m=0.8, seed=1)]
    a = _exr(tmp_path / "a.exr", _raycast_photo(default_blade(), w, shots[0]))
    # the same outline with another hamon: the overlap disagrees
    b = _exr(tmp_path / "b.exr", _raycast_photo(default_blade(), choji_map((128, 512), seed=3), shots[1]))
    out = tmp_path / "map.exr"
    _fails(capsys, ["map", a, b, "--mesh", str(blade_ply), "-o", str(out), "--resolution", "128", "512"],
           "b.exr", "different blades")
    # the whole of another blade (more sori, shorter): its outline does not register on this mesh
    whole = Shot(width=1200, height=400, tilt_deg=8, roll_deg=3)
    c = _exr(tmp_path / "c.exr", _raycast_photo(build_blade(KatanaSpec(nagasa=0.62, sori=0.035)), w, whole))
    _fails(capsys, ["map", a, c, "--mesh", str(blade_ply), "-o", str(out), "--resolution", "128", "512"],
           "c.exr", "did not converge")
    assert not out.exists()


def test_clicked_points(tmp_path, capsys, blade_ply):
    """--points: a photo's clicked (x, y) ↔ (u, v) pairs join the fit; fewer than 3 are refused naming the field."""
    import json

    from validation.photos import Shot, _spec, camera_frame

    from jkatana.cli import main
    from jkatana.maps import default_map
    from jkatana.maps.surface import blade_surface
    from jkatana.shape.katana import default_blade

    mesh = default_blade()
    shot = Shot(width=1200, height=400, tilt_deg=8, roll_deg=3)
    photo = _exr(tmp_path / "p.exr", _raycast_photo(mesh, default_map((128, 512)).w, shot))
    origin, target, up = camera_frame(_spec(mesh), shot)
    fwd = (target - origin) / np.linalg.norm(target - origin)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    f = (shot.width / 2) / (0.5 * shot.span_m / shot.distance_m)
    surf = blade_surface(mesh, (128, 512))
    pts = []
    for u, v in ((0.1, 0.2), (0.5, 0.8), (0.9, 0.3), (0.3, 0.5)):
        X = surf.points["omote"][int(v * 128), int(u * 512)] - origin
        x = f * (X @ right) / (X @ fwd) + shot.width / 2 - 0.5
        y = f * (X @ down) / (X @ fwd) + shot.height / 2 - 0.5
        pts.append([float(x), float(y), (int(u * 512) + 0.5) / 512, (int(v * 128) + 0.5) / 128])
    clicks = tmp_path / "clicks.json"
    clicks.write_text(json.dumps({"p.exr": {"side": "omote", "points": pts}}))
    out = tmp_path / "map.exr"
    capsys.readouterr()
    assert main(["map", photo, "--mesh", str(blade_ply), "-o", str(out), "--points", str(clicks),
                 "--resolution", "128", "512"]) == 0
    report = json.loads((tmp_path / "map_registration.json").read_text())
    assert report["photos"][0]["side"] == "omote" and report["photos"][0]["residual_px"] < 1.0
    clicks.write_text(json.dumps({"p.exr": {"side": "omote", "points": pts[:2]}}))
    _fails(capsys, ["map", photo, "--mesh", str(blade_ply), "-o", str(tmp_path / "m2.exr"), "--points", str(clicks)],
           "clicks.json", "'points'")

"""The fault harness: every class of bad input gives one line and exit 2, or a correct output; nothing is lost.

Classes (each with at least one case here, on tiny inputs): output paths (unwritable folder, parent is a
file, target is a folder, ``..``, an input as output, wrong extension, two outputs in one file), file
permissions, checked CLI numbers and budgets, memory- and work-bounded sizes (refused under 1 GB; no wavelength
step under 1 nm), physical bounds of parameters, environments and gains, malformed inputs (duplicate
columns, booleans as numbers, NUL bytes, non-UTF-8 text, corrupt images, header-only HDR, inconsistent
RAW levels, JSON of the wrong shape), no NaN written, resume with changed inputs (simulate, render) and of a
truncated capture (verified by checksum), parameter files between
commands, unreachable scheduler, interrupts (SIGINT/SIGTERM: exit 130/143, one line, nothing partial,
rerun resumes). Most cases call :func:`jkatana.cli.main` in-process: they fail before any work starts.
Interrupts need a real process; the 20-interrupt runs are ``slow``.
"""

from __future__ import annotations

import json
import os
import random
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from jkatana.cli import main
from jkatana.errors import InputError
from tests._scenes import CLI, cli_env, sphere_scene

#: The test sphere's wavelength grid here: 16 bands keep the command-line cases fast.
GRID = (400.0, 700.0, 20.0)

def run(argv, capsys) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def one_line(rc: int, err: str, *needles: str) -> str:
    """Exit 2 and exactly one non-empty stderr line that names each of ``needles``."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (rc, err)
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def no_temporaries(folder: Path) -> None:
    left = [p for p in folder.rglob(".*") if p.is_file() and not p.name.endswith(".inputs.json")
            and p.name != ".simulation-inputs.json"]
    assert not left, left


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A tiny simulated campaign (2 incidences, 24×24 frames) and its measured table."""
    from jkatana.measure.goniometer import Sensor, simulate_campaign
    from jkatana.measure.ingest import measure_to_file
    from jkatana.measure.protocol import Protocol

    out = tmp_path_factory.mktemp("campaign")
    simulate_campaign(out, Protocol(incidences_deg=(25.0, 45.0), dense_step_deg=5.0, sparse_step_deg=10.0),
                      sensor=Sensor(width=24, height=24), seed=1)
    measure_to_file(out / "manifest.csv", out / "table.csv", workers=1)
    return out


# ---------------------------------------------------------------- output paths, data loss, permissions

@pytest.mark.parametrize("argv, needle", [
    (["light", "build", "-o", "sky.png"], "--output"),            # the preview would overwrite the EXR
    (["light", "build", "-o", "/proc/sky.exr"], "not writable"),  # unwritable folder (also for root)
    (["light", "build", "-o", "afile/sky.exr"], "is a file"),     # parent is a file
    (["light", "build", "-o", "adir"], "is a folder"),            # target is a folder
    (["light", "build", "-o", ".."], "--output"),                 # no hidden '...exr'
    (["map", "--default", "-o", "m.png"], ".exr"),                # extension of what is written
    (["shape", "--blade", "-o", "afile/b.ply"], "is a file"),
    (["demo", "-o", "afile"], "not a folder"),
    (["view", "-o", "afile"], "not a folder"),
    (["simulate", "-o", "afile"], "not a folder"),
])
def test_output_path_refused_before_work(argv, needle, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    rc, _, err = run(argv, capsys)
    one_line(rc, err, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile"]  # nothing written


def test_outputs_never_overwrite_inputs(campaign, tmp_path, capsys):
    before = {p: p.read_bytes() for p in (campaign / "manifest.csv", campaign / "table.csv")}
    rc, _, err = run(["measure", campaign / "manifest.csv", "-o", campaign / "manifest.csv", "--quiet"], capsys)
    one_line(rc, err, "inputs")
    rc, _, err = run(["measure", campaign / "manifest.csv", "-o", tmp_path / "t.csv", "--plot",
                      campaign / "raw" / "i25.0_r10.0.dng", "--quiet"], capsys)
    one_line(rc, err, "--plot")
    rc, _, err = run(["fit", campaign / "table.csv", "-o", campaign / "table.json", "--seed", "-1"], capsys)
    one_line(rc, err, "--seed")
    rc, _, err = run(["light", "convert", campaign / "table.csv", "-o", campaign / "table.csv"], capsys)
    one_line(rc, err)
    assert {p: p.read_bytes() for p in before} == before


def test_outputs_get_the_umask_permissions(tmp_path):
    from jkatana.io.atomic import file_mode, write_text

    old = os.umask(0o022)
    file_mode.cache_clear()
    try:
        p = tmp_path / "a.txt"
        p.write_text("old")
        os.chmod(p, 0o600)
        write_text(p, "new")  # an overwrite gets the umask's mode, not the temporary's 0600
        assert stat.S_IMODE(p.stat().st_mode) == 0o644
        os.umask(0o077)
        file_mode.cache_clear()
        write_text(tmp_path / "b.txt", "x")
        assert stat.S_IMODE((tmp_path / "b.txt").stat().st_mode) == 0o600
    finally:
        os.umask(old)
        file_mode.cache_clear()
    assert not list(tmp_path.glob(".*"))


# ---------------------------------------------------------------- checked numbers

@pytest.mark.parametrize("argv, field", [
    (["simulate", "-o", "s", "--exposure", "-1"], "--exposure"),
    (["simulate", "-o", "s", "--exposure", "nan"], "--exposure"),
    (["simulate", "-o", "s", "--exposure", "inf"], "--exposure"),
    (["simulate", "-o", "s", "--jitter", "-1"], "--jitter"),
    (["simulate", "-o", "s", "--tilt", "nan"], "--tilt"),
    (["simulate", "-o", "s", "--seed", "-1"], "--seed"),
    (["simulate", "-o", "s", "--params", "hiraji:chi=nan"], "--params"),
    (["fit", "t.csv", "-o", "f.json", "--seed", "-1"], "--seed"),
    (["fit", "t.csv", "-o", "f.json", "--bootstrap", "-1"], "--bootstrap"),        # was a traceback
    (["fit", "t.csv", "-o", "f.json", "--bootstrap", "100000000"], "--bootstrap"),  # was work without a bound
    (["brdf", "slice", "x.binary", "-o", "t.csv", "--seed", "-1"], "--seed"),
    (["shape", "--simulate", "-o", "b.ply", "--smooth", "-1"], "--smooth"),
    (["shape", "m.ply", "-o", "b.ply", "--crease-deg", "nan"], "--crease-deg"),
    (["light", "build", "-o", "s.exr", "--azimuth", "inf"], "--azimuth"),
    (["light", "build", "-o", "s.exr", "--grid", "700", "400", "5"], "--grid"),
    (["light", "convert", "x.hdr", "-o", "s.exr", "--scale", "nan"], "--scale"),
    (["light", "convert", "x.hdr", "-o", "s.exr", "--scale", "-1"], "--scale"),
    (["shape", "--simulate", "-o", "b.ply", "--max-points", "-1"], "--max-points"),
    (["shape", "--simulate", "-o", "b.ply", "--patches", "100000", "6"], "--patches"),
    (["map", "--default", "-o", "m.exr", "--resolution", "-4", "16"], "--resolution"),
    (["map", "photo.png", "-o", "m.exr", "--aspect", "0"], "--aspect"),
    (["render", "scene.toml", "--samples", "-4"], "--samples"),
    (["render", "scene.toml", "--samples", "0"], "--samples"),   # not "the scene's count"
    (["render", "scene.toml", "--samples", "1000000000"], "--samples"),
    (["render", "scene.toml", "--devices", "100000"], "--devices"),
    (["render", "scene.toml", "--dask", "--workers", "0"], "--workers"),
    (["demo", "-o", "d", "--samples", "-4"], "--samples"),
    (["view", "--resolution", "0", "0"], "--resolution"),
    (["view", "--msaa", "-1"], "--msaa"),
    (["measure", "m.csv", "-o", "t.csv", "--workers", "-2"], "--workers"),
])
def test_cli_numbers_checked_in_one_line(argv, field, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    rc, _, err = run(argv, capsys)
    one_line(rc, err, field)
    assert time.perf_counter() - t0 < 30
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- memory-bounded sizes

MEMORY_CASES = [
    (["simulate", "-o", "s", "--size", "100000", "100000"], "--size"),
    (["light", "build", "-o", "s.exr", "--resolution", "100000", "100000"], "--resolution"),
    (["light", "--max-memory", "1G", "build", "-o", "s.exr", "--grid", "360", "720", "1"], "--resolution"),
    (["shape", "--simulate", "-o", "b.ply", "--scan-resolution", "60000", "60000"], "--scan-resolution"),
    (["map", "--default", "-o", "m.exr", "--resolution", "60000", "60000"], "--resolution"),
    (["demo", "-o", "d", "--resolution", "8000", "8000", "--max-memory", "2G"], "camera.resolution"),
    (["view", "--resolution", "16000", "16000", "--msaa", "16"], "--resolution"),
    (["map", "--default", "-o", "m.exr", "--max-memory", "1M"], "--max-memory"),
]


@pytest.mark.parametrize("argv, field", MEMORY_CASES)
def test_oversized_requests_refused_naming_field_and_estimate(argv, field, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    rc, _, err = run(argv, capsys)
    line = one_line(rc, err, field, "needs about")
    assert "iB" in line
    assert not any(tmp_path.iterdir())


def test_refused_requests_stay_under_1_gb(tmp_path):
    """All oversized requests in one process: its peak resident memory stays under 1 GB."""
    # the peak of this process's own address space (VmHWM starts anew at exec; getrusage's ru_maxrss
    # would carry over the forking pytest worker's peak)
    code = textwrap.dedent(f"""
        import sys
        from jkatana.cli import main

        def peak():
            for line in open("/proc/self/status"):
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024

        cases = {[c[0] for c in MEMORY_CASES]!r}
        codes, peaks = [], []
        for a in cases:
            codes.append(main(a))
            peaks.append(peak())
        print(peaks, file=sys.stderr)
        print(codes, peaks[-1])
    """)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=cli_env(), capture_output=True, text=True,
                       timeout=300)
    codes, peak = r.stdout.strip().rsplit(" ", 1)[0], int(r.stdout.strip().rsplit(" ", 1)[1])
    assert codes == str([2] * len(MEMORY_CASES)), r.stderr
    assert peak < 1e9, (peak, r.stderr.splitlines()[-1])  # peak after each case, in order
    assert "Traceback" not in r.stderr


# ---------------------------------------------------------------- malformed inputs

def _manifest(campaign: Path, folder: Path, header: str, row: str) -> Path:
    import shutil

    shutil.copytree(campaign / "raw", folder / "raw", dirs_exist_ok=True)
    p = folder / "m.csv"
    p.write_text(header + "\n" + row + "\n")
    return p


def test_duplicate_manifest_and_table_columns_refused(campaign, tmp_path, capsys):
    m = _manifest(campaign, tmp_path, "file,region,theta_i_deg,theta_r_deg,roi,roi",
                  "raw/i25.0_r10.0.dng,hiraji,25,10,2 2 8 8,12 2 8 8")
    rc, _, err = run(["measure", m, "-o", tmp_path / "t.csv", "--quiet"], capsys)
    one_line(rc, err, "'roi'", "more than once")
    t = tmp_path / "dup.csv"
    text = (campaign / "table.csv").read_text().splitlines()
    t.write_text("\n".join([text[0] + ",value"] + [r + ",1" for r in text[1:]]) + "\n")
    rc, _, err = run(["fit", t, "-o", tmp_path / "f.json"], capsys)
    one_line(rc, err, "'value'")
    assert not (tmp_path / "t.csv").exists() and not (tmp_path / "f.json").exists()


def test_toml_boolean_is_not_a_number_and_nul_path_refused(campaign, tmp_path, capsys):
    import shutil

    shutil.copytree(campaign / "raw", tmp_path / "raw")
    (tmp_path / "m.toml").write_text(textwrap.dedent("""
        [[capture]]
        file = "raw/i25.0_r10.0.dng"
        region = "hiraji"
        theta_i_deg = 25
        theta_r_deg = 10
        roi = [[2, 2, 8, 8]]
        exposure_s = true
    """))
    rc, _, err = run(["measure", tmp_path / "m.toml", "-o", tmp_path / "t.csv", "--quiet"], capsys)
    one_line(rc, err, "exposure_s", "not a number")
    m = _manifest(campaign, tmp_path, "file,region,theta_i_deg,theta_r_deg,roi",
                  "raw/i25.0\x00_r10.0.dng,hiraji,25,10,2 2 8 8")
    rc, _, err = run(["measure", m, "-o", tmp_path / "t.csv", "--quiet"], capsys)
    one_line(rc, err, "NUL")


def test_non_utf8_json_and_yaml_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.json").write_bytes(b'\xff\xfe{"format": 1}')
    rc, _, err = run(["report", "p.json", "-o", "rep"], capsys)
    one_line(rc, err, "p.json", "UTF-8")
    rc, _, err = run(["map", "photo.exr", "-o", "m.exr", "--hiraji", "p.json"], capsys)
    one_line(rc, err)
    (tmp_path / "n.yml").write_bytes(b"\xff\xfedata: [1, 2\n")
    (tmp_path / "bad.yml").write_text("data: [1, 2\n  - x: :\n")
    for name in ("n.yml", "bad.yml"):
        rc, _, err = run(["simulate", "-o", "s", "--optical-constants", name, "--incidences", "25", "--size", "24",
                          "24", "--quiet"], capsys)
        one_line(rc, err, name)


def test_corrupt_png_and_header_only_hdr_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    rc, _, err = run(["map", "photo.png", "-o", "m.exr"], capsys)
    one_line(rc, err, "photo.png", "PNG")
    (tmp_path / "h.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16 +X 32\n")
    rc, _, err = run(["light", "convert", "h.hdr", "-o", "s.exr", "--grid", "400", "700", "50"], capsys)
    one_line(rc, err, "h.hdr")
    assert not (tmp_path / "s.exr").exists() and not (tmp_path / "m.exr").exists()


def test_raw_white_level_below_black_level_refused(tmp_path, capsys):
    from jkatana.measure.goniometer import write_dng

    img = np.full((24, 24), 4095, np.uint16)
    write_dng(tmp_path / "c.dng", img, black=(4096,) * 4, white=4095, exposure_s=0.01)
    (tmp_path / "m.csv").write_text("file,region,theta_i_deg,theta_r_deg,roi\nc.dng,hiraji,25,20,2 2 8 8\n")
    rc, _, err = run(["measure", tmp_path / "m.csv", "-o", tmp_path / "t.csv", "--quiet"], capsys)
    one_line(rc, err, "white level", "black level")


def test_non_utf8_file_name_is_read(tmp_path, capsys):
    from jkatana.io.exr import read_exr, write_exr

    name = tmp_path / os.fsdecode(b"env\xff.exr")
    write_exr(name, {c: np.ones((8, 16)) for c in "RGB"})
    assert sorted(read_exr(name)[0]) == ["B", "G", "R"]


# ---------------------------------------------------------------- nothing non-finite written

def test_no_nan_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    from jkatana.measure.goniometer import Sensor, simulate_campaign

    for kw, field in ((dict(tilt_deg=float("nan")), "tilt"), (dict(angle_jitter_deg=float("nan")), "jitter"),
                      (dict(params={"hiraji": {"chi": float("nan"), "mu": 0.05}}), "chi")):
        with pytest.raises(InputError, match=field):
            simulate_campaign(tmp_path / "s", [(25.0, 25.0)], sensor=Sensor(width=24, height=24), **kw)
    assert not (tmp_path / "s" / "truth.csv").exists()
    rc, _, err = run(["light", "build", "-o", "s.exr", "--resolution", "4", "8", "--grid", "400", "700", "50"],
                     capsys)
    assert rc == 0
    from jkatana.light.spectral_exr import read_spectral_exr_raw

    assert np.isfinite(read_spectral_exr_raw(tmp_path / "s.exr")[1]).all()


def test_fit_refuses_unusable_tables(campaign, tmp_path, capsys):
    lines = (campaign / "table.csv").read_text().splitlines()
    (tmp_path / "one.csv").write_text("\n".join(lines[:2]) + "\n")
    rc, _, err = run(["fit", tmp_path / "one.csv", "-o", tmp_path / "f.json"], capsys)
    one_line(rc, err, "usable row")
    header = lines[0].split(",")
    iv = header.index("value")
    rows = [r.split(",") for r in lines[1:]]
    for r in rows:
        r[iv] = "1e308"
    (tmp_path / "big.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    rc, _, err = run(["fit", tmp_path / "big.csv", "--region", "hiraji", "-o", tmp_path / "f.json"], capsys)
    one_line(rc, err, "1e150")


# ---------------------------------------------------------------- resume means same inputs

def test_simulate_resume_with_other_inputs_refused(tmp_path, capsys):
    base = ["simulate", "-o", tmp_path / "s", "--incidences", "25", "--dense-step", "5", "--sparse-step", "20",
            "--size", "24", "24", "--regions", "hiraji", "--quiet"]
    assert run(base, capsys)[0] == 0
    truth = (tmp_path / "s" / "truth.csv").read_bytes()
    assert run(base + ["--resume"], capsys)[0] == 0
    rc, _, err = run(base + ["--resume", "--params", "hiraji:chi=50000,mu=0.05"], capsys)
    one_line(rc, err, "params", "--resume")
    assert (tmp_path / "s" / "truth.csv").read_bytes() == truth


def test_render_resume_with_other_scene_refused(tmp_path):
    from jkatana.render.batch import _record, finished, plan_batch, plan_resume, scene_inputs
    from jkatana.render.scenefile import load_scene

    (tmp_path / "scene.toml").write_text(sphere_scene(48, 32, 4, spectral=GRID))
    scene = load_scene(tmp_path / "scene.toml")
    jobs = plan_batch(scene, 2, 1)
    inputs = scene_inputs(scene)
    for j in jobs:  # frames "finished" from these inputs
        for suffix in (".png", ".exr"):
            Path(j.stem).with_suffix(suffix).parent.mkdir(parents=True, exist_ok=True)
            Path(j.stem).with_suffix(suffix).write_bytes(b"x")
        _record(j, inputs)
    assert all(finished(j) for j in jobs)
    todo, skipped = plan_resume(jobs, scene_inputs(scene))
    assert todo == [] and len(skipped) == 2
    (tmp_path / "scene.toml").write_text(sphere_scene(64, 40, 8, spectral=GRID))
    changed = load_scene(tmp_path / "scene.toml")
    with pytest.raises(InputError, match=r"camera\.resolution.*samples|samples.*camera\.resolution"):
        plan_resume(plan_batch(changed, 2, 1), scene_inputs(changed))
    with pytest.raises(InputError, match="samples"):  # a command-line override counts as well
        plan_resume(jobs, scene_inputs(scene, samples=16))
    assert len(plan_resume(jobs, scene_inputs(changed), force=True)[0]) == 2


def test_unreachable_scheduler_refused_in_time(tmp_path):
    from jkatana.render.batch import plan_batch, run_batch_dask
    from jkatana.render.scenefile import load_scene

    (tmp_path / "scene.toml").write_text(sphere_scene(8, 8, 1, spectral=GRID))
    scene = load_scene(tmp_path / "scene.toml").with_output_directory(tmp_path / "out")
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="--scheduler"):
        run_batch_dask(tmp_path / "scene.toml", scene, plan_batch(scene, 1, 1), scheduler="tcp://127.0.0.1:9",
                       connect_timeout=2.0)
    assert time.perf_counter() - t0 < 60


# ---------------------------------------------------------------- scene fields (typed scene)

@pytest.mark.parametrize("old, new, field", [
    ('name = "f"\n', 'name = "f"\nspectral = "false"\n', "output.spectral"),
    ('name = "f"\n', 'name = ".."\n', "output.name"),
    ('resolution = [16, 32]\n', 'resolution = [16, 32]\nsun = "false"\n', "environment.sun"),
    ('samples = 1\n', 'samples = 1\nmode = "lowrank"\nrank = 64\n', "render.rank"),
    ('samples = 1\n', 'samples = 1\nsplit_sun = "yes"\n', "render.split_sun"),
    ('samples = 1\n', 'samples = 1\nmode = "paper-published"\nsplit_sun = true\n', "render.split_sun"),
    ('samples = 1\n', 'samples = 1\nenv_window = 0\n', "render.env_window"),
    ('samples = 1\n', 'samples = 1\nenv_window = "wide"\n', "render.env_window"),
    ('samples = 1\n', 'samples = 1\nenv_window = true\n', "render.env_window"),
])
def test_scene_fields_one_line(old, new, field, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = sphere_scene(8, 8, 1, spectral=GRID)
    assert old in text
    text = text.replace(old, new)
    (tmp_path / "scene.toml").write_text(text)
    rc, _, err = run(["render", "scene.toml"], capsys)
    one_line(rc, err, field)
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------- parameter files flow between commands

def test_map_and_report_accept_a_fit_parameter_file(tmp_path, capsys):
    from jkatana.fit.params import FORMAT, read_params
    from jkatana.maps.photo import load_region_parameters

    d = {"format": FORMAT, "region": "hiraji", "model": "hiraji", "values": {"chi": 79000.0, "mu": 0.05},
         "laplace": {"ci95": {}}, "optical_constants": "Fe-Johnson", "converged": True,
         "diagnostics": {"chi2_dof": 1.0}}
    p = tmp_path / "hiraji.json"
    p.write_text(json.dumps(d))
    read_params(p)  # a valid fit parameter file
    assert load_region_parameters(p, "hiraji") == {"chi": 79000.0, "mu0": 0.05}
    with pytest.raises(InputError, match="hamon"):
        load_region_parameters(p, "hamon")
    del d["diagnostics"]
    p.write_text(json.dumps(d))
    rc, _, err = run(["report", p, "-o", tmp_path / "rep"], capsys)
    one_line(rc, err, "diagnostics")


@pytest.mark.slow
def test_fit_output_feeds_map_and_report(campaign, tmp_path):
    r = subprocess.run(CLI + ["fit", campaign / "table.csv", "--region", "hiraji", "-o", tmp_path / "h.json"],
                       env=cli_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode in (0, 1), r.stderr
    (tmp_path / "photo.exr").parent.mkdir(exist_ok=True)
    from jkatana.io.exr import write_exr

    y = np.tile(np.linspace(0.1, 1.0, 64), (16, 1))
    write_exr(tmp_path / "photo.exr", {"Y": y})
    r = subprocess.run(CLI + ["map", tmp_path / "photo.exr", "-o", tmp_path / "m.exr", "--resolution", "8", "32",
                              "--hiraji", tmp_path / "h.json"], env=cli_env(), capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(CLI + ["report", tmp_path / "h.json", "-o", tmp_path / "rep"], env=cli_env(),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "rep" / "report.md").is_file()


# ---------------------------------------------------------------- interrupts

def _interrupt(argv, cwd: Path, after: float, sig=signal.SIGINT, timeout: float = 300, when=None,
               seen: str | None = None):
    """Start ``jkatana argv``; send ``sig`` after ``after`` s, or as soon as ``when()`` is true or ``seen``
    appears in its stderr (checked every 10 ms, at most ``after`` s), if it is still running; return
    (rc, stderr)."""
    import tempfile

    with tempfile.TemporaryFile("w+") as log:   # outside ``cwd``: the tests look there for temporaries
        proc = subprocess.Popen(CLI + [str(a) for a in argv], cwd=cwd, env=cli_env(), stdout=subprocess.DEVNULL,
                                stderr=log, text=True)

        def saw():
            log.seek(0)
            return seen in log.read()

        deadline = time.monotonic() + after
        while (proc.poll() is None and time.monotonic() < deadline and not (when is not None and when())
               and not (seen is not None and saw())):
            time.sleep(0.01)
        if proc.poll() is None:
            proc.send_signal(sig)
        proc.wait(timeout=timeout)
        log.seek(0)
        return proc.returncode, log.read()


def _clean_interrupt(rc, err, sig=signal.SIGINT):
    assert rc == 128 + sig, (rc, err)
    assert "Traceback" not in err and "Segmentation" not in err
    last = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()][-1]
    assert "interrupted" in last


@pytest.mark.slow
def test_sigint_during_fit_emcee_exits_130_without_output(campaign, tmp_path):
    rc, err = _interrupt(["fit", campaign / "table.csv", "--region", "hiraji", "-o", tmp_path / "f.json",
                          "--emcee"], tmp_path, after=120.0, seen="emcee")
    _clean_interrupt(rc, err)   # signalled once the sampler starts (its progress label), not after a set time
    assert not (tmp_path / "f.json").exists()
    no_temporaries(tmp_path)


@pytest.mark.slow
def test_sigterm_during_simulate_exits_143_and_resume_completes(tmp_path):
    argv = ["simulate", "-o", tmp_path / "s", "--incidences", "15", "25", "35", "45", "--dense-step", "0.5",
            "--sparse-step", "5", "--size", "24", "24", "--quiet"]
    raw = tmp_path / "s" / "raw"
    rc, err = _interrupt(argv, tmp_path, after=120.0, sig=signal.SIGTERM,
                         when=lambda: raw.is_dir() and len(list(raw.glob("*.dng"))) >= 3)
    _clean_interrupt(rc, err, signal.SIGTERM)   # mid-campaign: 3 of ~400 captures written
    assert not (tmp_path / "s" / "manifest.csv").exists()
    no_temporaries(tmp_path)
    kept = {p.name: p.stat().st_mtime_ns for p in raw.glob("*.dng")}
    r = subprocess.run(CLI + [str(a) for a in argv + ["--resume"]], cwd=tmp_path, env=cli_env(), capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "s" / "manifest.csv").is_file()
    assert {n: (raw / n).stat().st_mtime_ns for n in kept} == kept   # resumed: finished captures kept


@pytest.mark.slow
def test_twenty_interrupts_at_random_moments(campaign, tmp_path):
    """20 interrupts over `fit --emcee`, `measure` and `render --views 4`: every one exits 130 with one line
    (or the command had already finished: then tried again, up to three times, at moments within that run's
    own time), leaves no partial output, and a rerun resumes to completion."""
    import shutil

    rng = random.Random(17)
    # a campaign large enough that `measure` takes seconds
    big = tmp_path / "big"
    r = subprocess.run(CLI + ["simulate", "-o", big, "--size", "256", "256", "--quiet"], env=cli_env(),
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    (tmp_path / "scene.toml").write_text(sphere_scene(48, 32, 16, spectral=GRID))
    kinds = ["fit", "measure", "render"]

    def argv_for(kind, work):
        if kind == "fit":
            return ["fit", campaign / "table.csv", "--region", "hiraji", "-o", work / "f.json", "--emcee"]
        if kind == "measure":
            return ["measure", big / "manifest.csv", "-o", work / "t.csv", "--quiet"]
        shutil.copy(tmp_path / "scene.toml", work / "scene.toml")
        return ["render", work / "scene.toml", "--views", "4", "-o", work / "out"]

    # the moments lie within each command's own run time on this machine, measured uninterrupted on a second
    # run (the first fills JAX's persistent compilation cache, which the interrupted runs then read)
    moments, done_rc = {}, {}
    for kind in kinds:
        for attempt in range(2):
            work = tmp_path / f"timing-{kind}-{attempt}"
            work.mkdir()
            t0 = time.perf_counter()
            r = subprocess.run(CLI + [str(a) for a in argv_for(kind, work)], cwd=work, env=cli_env(),
                               capture_output=True, text=True, timeout=900)
            assert r.returncode in (0, 1), r.stderr
            t = time.perf_counter() - t0
        moments[kind], done_rc[kind] = (0.15 * t, 0.85 * t), r.returncode
    landed = 0
    for k in range(20):
        kind = kinds[k % 3]
        work = tmp_path / f"run{k}"
        out = {"fit": ["f.json"], "measure": ["t.csv"], "render": []}[kind]
        for attempt in range(3):
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir()
            argv = argv_for(kind, work)
            t0 = time.perf_counter()
            rc, err = _interrupt(argv, work, after=rng.uniform(*moments[kind]))
            if rc != done_rc[kind]:
                break
            # the command finished before the signal (fit: 1 = finished, not converged): on a machine shared
            # with other tests its time moves; the moments follow this run's, and the interrupt is tried again
            no_temporaries(work)
            elapsed = time.perf_counter() - t0
            moments[kind] = (0.15 * elapsed, 0.85 * elapsed)
        out = [work / p for p in out]
        if rc != done_rc[kind]:
            _clean_interrupt(rc, err)
            landed += 1
            for p in out:  # nothing partial: absent, or complete (an interrupt just after the atomic rename)
                assert not p.exists() or (json.loads(p.read_text()) if p.suffix == ".json"
                                          else len(p.read_text().splitlines()) > 1)
        no_temporaries(work)
        r = subprocess.run(CLI + [str(a) for a in argv], cwd=work, env=cli_env(), capture_output=True, text=True,
                           timeout=900)
        assert r.returncode in (0, 1), r.stderr  # fit: 1 = finished, not converged
        for p in out:
            assert p.is_file()
        if kind == "render":
            assert len([p for p in (work / "out").glob("*.png") if not p.name.startswith(".")]) == 4
    assert landed >= 15, landed   # most interrupts came mid-run


# ---------------------------------------------------------------- physical bounds of the inputs

def _params_file(folder: Path, name: str = "p.json", text: str | None = None, **change) -> Path:
    """A valid hiraji parameter file (``change`` replaces top-level fields), or ``text`` as it is."""
    from jkatana.fit.params import FORMAT

    d = {"format": FORMAT, "region": "hiraji", "model": "hiraji", "values": {"chi": 79000.0, "mu": 0.05},
         "laplace": {"ci95": {}}, "optical_constants": "Fe-Johnson", "converged": True,
         "diagnostics": {"chi2_dof": 1.0}} | change
    p = folder / name
    p.write_text(text if text is not None else json.dumps(d))
    return p


SIM = ["simulate", "-o", "s", "--incidences", "25", "--dense-step", "5", "--sparse-step", "20", "--size", "24", "24",
       "--quiet"]


@pytest.mark.parametrize("argv, needles", [
    (SIM + ["--params", "hiraji:chi=79000,mu=0"], ["params.hiraji.mu", "> 0"]),
    (SIM + ["--params", "hiraji:mu=-0.05"], ["params.hiraji.mu", "> 0"]),
    (SIM + ["--params", "hiraji:chi=0"], ["params.hiraji.chi", "> 0"]),
    (SIM + ["--params", "kissaki:chi=79000,mu=0.05"], ["params", "unknown region 'kissaki'"]),
    (SIM + ["--regions", "hiraji", "--params", "hamon:mu=0.05"], ["params", "'hamon'", "not simulated"]),
    (["report", "nan.json", "-o", "rep"], ["nan.json", "values.mu", "NaN"]),
    (["report", "zero.json", "-o", "rep"], ["zero.json", "values.mu", "> 0"]),
    (["report", "region.json", "-o", "rep"], ["region.json", "'region'", "unknown region"]),
    (["map", "flat.exr", "-o", "m.exr", "--resolution", "8", "32"], ["flat.exr", "no contrast", "--dark"]),
    (["map", "photo.exr", "-o", "m.exr", "--resolution", "8", "32", "--hiraji", "zero.json"],
     ["zero.json", "values.mu", "> 0"]),
    (["light", "convert", "nan.exr", "-o", "s.exr", "--grid", "400", "700", "50"],
     ["nan.exr", "2 of 128 pixels", "NaN or infinite"]),
])
def test_invalid_physical_parameters_refused(argv, needles, tmp_path, monkeypatch, capsys):
    """A width of zero or below, an unknown region, a NaN width, a photo without contrast, non-finite pixels:
    one line naming the file and field, exit 2, nothing written."""
    from jkatana.io.exr import write_exr

    monkeypatch.chdir(tmp_path)
    _params_file(tmp_path, "nan.json", text=_params_file(tmp_path).read_text().replace('"mu": 0.05', '"mu": NaN'))
    _params_file(tmp_path, "zero.json", values={"chi": 79000.0, "mu": 0.0})
    _params_file(tmp_path, "region.json", region="kissaki")
    write_exr(tmp_path / "photo.exr", {"Y": np.tile(np.linspace(0.1, 1.0, 64), (16, 1))})
    write_exr(tmp_path / "flat.exr", {"Y": np.full((16, 64), 0.4)})
    rgb = np.ones((8, 16))
    rgb[1, 2], rgb[3, 3] = np.nan, np.inf
    write_exr(tmp_path / "nan.exr", {"R": rgb, "G": np.ones((8, 16)), "B": np.ones((8, 16))})
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, _, err = run(argv, capsys)
    one_line(rc, err, *needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == before   # nothing written


def test_manifest_gain_beyond_bound_refused(campaign, tmp_path, capsys):
    import shutil

    shutil.copytree(campaign / "raw", tmp_path / "raw")
    text = (campaign / "manifest.csv").read_text().splitlines()
    gain = text[0].split(",").index("gain")
    row = text[1].split(",")
    row[gain] = "1e308"   # finite, but the values it makes cannot be squared in the fit
    (tmp_path / "m.csv").write_text("\n".join([text[0], ",".join(row)] + text[2:]) + "\n")
    rc, _, err = run(["measure", tmp_path / "m.csv", "-o", tmp_path / "t.csv", "--quiet"], capsys)
    one_line(rc, err, "m.csv", "row 1", "'gain'", "1e+150")
    assert not (tmp_path / "t.csv").exists()


def test_clamped_environment_pixels_counted_in_one_warning(tmp_path):
    """Negative pixels (colours outside the gamut) are clamped to 0, and one warning line says how many."""
    from jkatana.io.exr import write_exr
    from jkatana.light.spectral_exr import read_spectral_exr_raw

    r = np.ones((8, 16))
    r[2, 3], r[4, 4], r[5, 9] = -0.5, -1.0, -1e-3
    write_exr(tmp_path / "neg.exr", {"R": r, "G": np.ones((8, 16)), "B": np.ones((8, 16))})
    p = subprocess.run(CLI + ["light", "convert", "neg.exr", "-o", "s.exr", "--grid", "400", "700", "50"],
                       cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "warning" in lines[0] and "3 of 128 pixels" in lines[0] and "clamped" in lines[0], \
        p.stderr
    assert (read_spectral_exr_raw(tmp_path / "s.exr")[1] >= 0).all()


# ---------------------------------------------------------------- resume verifies what it keeps

#: ``jkatana simulate`` whose 4th capture is left half written at its own name, and the process killed with SIGKILL
#: (nothing runs after: no handler, no clean-up). An atomic write cannot leave that under a plain kill; a crash
#: can, when the rename reached the disk before the data. A stray temporary of the 5th capture, half written, is
#: left as a kill during its write leaves one.
_KILLED_MID_CAPTURE = textwrap.dedent("""
    import os, signal, sys
    import jkatana.measure.goniometer as g

    real, calls = g.write_dng, []

    def write_dng(path, image, **kw):
        calls.append(path)
        if len(calls) == 4:
            real(path, image, **kw)
            data = path.read_bytes()
            path.write_bytes(data[: len(data) // 2])
            (path.parent / f".{path.stem}.x1y2z3.dng").write_bytes(data[: len(data) // 3])
            os.kill(os.getpid(), signal.SIGKILL)
        return real(path, image, **kw)

    g.write_dng = write_dng
    from jkatana.cli import main
    sys.exit(main())
""")


@pytest.mark.slow
def test_resume_after_kill_mid_capture_redoes_the_truncated_capture(tmp_path):
    from jkatana.measure.decode import read_frame

    argv = ["simulate", "--incidences", "25", "--dense-step", "5", "--sparse-step", "20", "--size", "24", "24",
            "--quiet"]
    r = subprocess.run([sys.executable, "-c", _KILLED_MID_CAPTURE] + argv + ["-o", "killed"], cwd=tmp_path,
                       env=cli_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == -signal.SIGKILL, (r.returncode, r.stderr)
    raw = tmp_path / "killed" / "raw"
    captures = sorted(p for p in raw.glob("*.dng") if not p.name.startswith("."))
    half = captures[-1]
    assert len(captures) == 4 and list(raw.glob(".*.dng"))
    with pytest.raises(InputError):
        read_frame(half)   # the capture the kill left truncated
    r = subprocess.run(CLI + argv + ["-o", "killed", "--resume"], cwd=tmp_path, env=cli_env(), capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(CLI + argv + ["-o", "whole"], cwd=tmp_path, env=cli_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    killed = {p.relative_to(tmp_path / "killed"): p.read_bytes() for p in (tmp_path / "killed").rglob("*")
              if p.is_file()}
    whole = {p.relative_to(tmp_path / "whole"): p.read_bytes() for p in (tmp_path / "whole").rglob("*")
             if p.is_file()}
    assert sorted(killed) == sorted(whole)   # the stray temporary is gone
    assert killed == whole                   # byte for byte: captures, manifest, truth, checksums
    for p in raw.glob("*.dng"):
        assert read_frame(p).dn.size == 24 * 24   # every capture decodes (and no temporary is left)


# ---------------------------------------------------------------- JSON of the wrong shape

@pytest.mark.parametrize("text, needles", [
    ("[1, 2]", ["(top level)", "must be an object"]),
    ('{"format": "jkatana-params/1", "model": "hiraji", "values": [79000, 0.05]}', ["'values'", "must be an object"]),
    ('{"parameters": {"chi": {"value": "79000"}, "mu": 0.05}}', ["'parameters.chi'", "must be a number"]),
    ('{"chi": 79000, "mu0": true}', ["'mu0'", "must be a number"]),
    ('{"chi": 79000, "mu0": [0.05]}', ["'mu0'", "must be a number"]),
    ('{"chi": 79000, "mu0": -Infinity}', ["'mu0'", "-Infinity"]),
    ('{"chi": 79000', ["not JSON", "line 1"]),
])
def test_parameter_file_of_wrong_json_shape_one_line(text, needles, tmp_path, monkeypatch, capsys):
    from jkatana.io.exr import write_exr

    monkeypatch.chdir(tmp_path)
    write_exr(tmp_path / "photo.exr", {"Y": np.tile(np.linspace(0.1, 1.0, 64), (16, 1))})
    (tmp_path / "h.json").write_text(text)
    rc, _, err = run(["map", "photo.exr", "-o", "m.exr", "--resolution", "8", "32", "--hiraji", "h.json"], capsys)
    one_line(rc, err, "h.json", *needles)
    assert not (tmp_path / "m.exr").exists()


@pytest.mark.parametrize("change, field", [
    (dict(laplace=[1, 2]), "'laplace'"),
    (dict(laplace={"ci95": {"mu": "wide"}}), "'laplace.ci95.mu'"),
    (dict(diagnostics=[]), "'diagnostics'"),
    (dict(values={"chi": "79000", "mu": 0.05}), "'values.chi'"),
    (dict(converged="yes"), "'converged'"),
])
def test_report_parameter_file_of_wrong_shape_one_line(change, field, tmp_path, capsys):
    p = _params_file(tmp_path, **change)
    rc, _, err = run(["report", p, "-o", tmp_path / "rep"], capsys)
    one_line(rc, err, "p.json", field)
    assert not (tmp_path / "rep").exists()


# ---------------------------------------------------------------- work with a bound

@pytest.mark.parametrize("argv, needles", [
    (["light", "build", "-o", "s.exr", "--resolution", "4", "8", "--grid", "400", "700", "0.001"],
     ["--grid", "below 1 nm"]),
    (["light", "build", "-o", "s.exr", "--resolution", "4", "8", "--grid", "500", "500.3", "0.001"],
     ["--grid", "below 1 nm"]),
    (["light", "build", "-o", "s.exr", "--resolution", "4", "8", "--grid", "200", "700", "5"], ["--grid", "360–830"]),
    (["light", "convert", "x.hdr", "-o", "s.exr", "--grid", "400", "700", "0.5"], ["--grid", "below 1 nm"]),
])
def test_work_without_bound_refused_at_once(argv, needles, tmp_path, monkeypatch, capsys):
    """A 0.001 nm grid (300 001 bands) on a 4×8 map ran past four minutes: a step below 1 nm (the CIE CMFs'
    table step, the finest data jkatana reads) is refused before any work."""
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    rc, _, err = run(argv, capsys)
    one_line(rc, err, *needles)
    assert time.perf_counter() - t0 < 30
    assert not any(tmp_path.iterdir())


def test_environment_work_beyond_its_limit_refused():
    """Within the memory a machine has, a sky of more spectral values than one environment may hold is refused by
    the work estimate, naming the option and the count (memory is checked first, so this calls the estimate)."""
    from jkatana.io.limits import ENV_VALUES, require_work

    require_work(512 * 1024 * 361, "--resolution", "a sky")   # 1.9e8 values: 103 s on 2 cores, allowed
    with pytest.raises(InputError, match=r"--resolution.*7\.57e\+08 spectral values.*2\.68e\+08"):
        require_work(1024 * 2048 * 361, "--resolution", "a 1024×2048 sky with 361 bands")
    assert ENV_VALUES == 1 << 28


# ---------------------------------------------------------------- budgets

@pytest.mark.parametrize("argv, field", [
    (["bench", "--budget", "-1"], "--budget-total"),     # argparse's prefix of --budget-total
    (["bench", "--budget-total", "0"], "--budget-total"),
    (["bench", "--budget-total", "nan"], "--budget-total"),
    (["bench", "--timeout", "-5"], "--timeout"),
    (["bench", "--timeout", "inf"], "--timeout"),
])
def test_non_positive_budgets_refused_before_work(argv, field, tmp_path, capsys):
    out = tmp_path / "r.json"
    t0 = time.perf_counter()
    rc, _, err = run(argv + ["--only", "bench_models", "-o", out], capsys)
    one_line(rc, err, field)
    assert time.perf_counter() - t0 < 10 and not out.exists()

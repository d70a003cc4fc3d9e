"""Property-based fault tests over the parameter-file (JSON) and scene (TOML) schemas.

Random documents of the right shape and of the wrong one: a valid parameter file or the test sphere's scene
with some fields replaced by random values (numbers in and out of range, zero, NaN, ±inf, 1e300, booleans,
strings, lists, tables), or random JSON altogether. Every input is either accepted, and then what consumes it
gives finite numbers (a reflectance map from ``jkatana map --hiraji``, the renderer's material, a small render),
or refused with an :class:`~jkatana.errors.InputError` of one line. Any other exception is a defect.

The everyday suite draws few examples (renders are 8×8 pixels, 1 sample, 16 bands, and only for small accepted
scenes); ``test_*_many`` draw many more and are marked ``slow``.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings, strategies as st

from jkatana.cli import main
from jkatana.errors import InputError
from tests._scenes import sphere_scene

GRID = (400.0, 700.0, 20.0)
EVERYDAY = settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
MANY = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))

#: Numbers a hand-edited or machine-mangled file holds: ordinary, boundary and absurd.
NUMBERS = st.one_of(
    st.floats(-2.0, 2.0), st.integers(-3, 50),
    st.sampled_from([0, 0.0, -0.0, 1e-300, 5e-324, 1e150, 1e300, 1.7e308, -1e300, math.nan, math.inf, -math.inf,
                     79000.0, 0.05, 2 ** 53]),
)
_SCALARS = st.one_of(NUMBERS, st.booleans(), st.text(max_size=6))
#: Any JSON value (with the NaN/Infinity literals Python's json writes).
JSON = st.recursive(st.none() | _SCALARS, lambda c: st.lists(c, max_size=3) | st.dictionaries(
    st.text(max_size=6), c, max_size=3), max_leaves=6)
#: Any TOML value (no null in TOML).
TOML = st.recursive(_SCALARS, lambda c: st.lists(c, max_size=3) | st.dictionaries(
    st.text(min_size=1, max_size=6), c, max_size=3), max_leaves=6)


def _one_line(err: InputError) -> None:
    text = str(err)
    assert text and "\n" not in text and "Traceback" not in text, text


# ---------------------------------------------------------------- parameter files

def _valid_params() -> dict:
    from jkatana.fit.params import FORMAT

    return {"format": FORMAT, "region": "hiraji", "model": "hiraji", "values": {"chi": 79000.0, "mu": 0.05},
            "laplace": {"ci95": {"mu": [0.04, 0.06]}}, "optical_constants": "Fe-Johnson", "converged": True,
            "diagnostics": {"chi2_dof": 1.0}, "lobe": {"lobe": "gaussian", "mu": 0.05}}


def _numeric_leaves(doc, where=()):
    """Paths to the numbers in a JSON/TOML document (booleans are not numbers)."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _numeric_leaves(v, where + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _numeric_leaves(v, where + (i,))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
        yield where


def _containers(doc, where=()):
    """Paths to the objects/tables and arrays below the top of a document."""
    if isinstance(doc, (dict, list)):
        if where:
            yield where
        for k, v in (doc.items() if isinstance(doc, dict) else enumerate(doc)):
            yield from _containers(v, where + (k,))


def _get(doc, where):
    for k in where:
        doc = doc[k]
    return doc


def _set(doc, where, value):
    for k in where[:-1]:
        doc = doc[k]
    doc[where[-1]] = value


@st.composite
def _mutate(draw, doc: dict, extra_keys: dict, any_value) -> None:
    """Mutate ``doc`` in place 1–3 times: often a number replaced by another (the right shape, any value), else
    an object or array given the other shape (an array of an object's values, an object of an array's items, a
    scalar), a field replaced by any value, removed, added, or a whole section replaced."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["number"] * 4 + ["shape"] * 2 + ["value"] * 2 + ["remove", "add", "section"]))
        leaves = sorted(_numeric_leaves(doc), key=str)
        if kind == "number" and leaves:
            _set(doc, draw(st.sampled_from(leaves)), draw(NUMBERS))
            continue
        containers = sorted(_containers(doc), key=str)
        if kind == "shape" and containers:
            where = draw(st.sampled_from(containers))
            node = _get(doc, where)
            other = list(node.values()) if isinstance(node, dict) else {str(i): v for i, v in enumerate(node)}
            _set(doc, where, draw(st.sampled_from([other, "text", 1.0, True])))
            continue
        section = draw(st.sampled_from(sorted(set(doc) | set(extra_keys))))
        if kind == "section":
            doc[section] = draw(any_value)
            continue
        table = doc.setdefault(section, {}) if section in extra_keys else doc
        if not isinstance(table, dict):
            continue
        key = draw(st.sampled_from(sorted(table) + extra_keys.get(section, ["extra"]))) \
            if section in extra_keys else section
        if kind == "remove":
            table.pop(key, None)
        else:
            table[key] = draw(NUMBERS if kind == "add" else any_value)


#: Fields a parameter file may hold beyond the valid one's, per object (the top level is ``""``).
_PARAMS_KEYS = {"values": ["mu0", "chi", "tilt_deg", "floor", "extra"], "lobe": ["mu", "alpha", "extra"],
                "laplace": ["ci95", "se"], "diagnostics": ["chi2_dof"]}


@st.composite
def params_documents(draw):
    """A parameter file's JSON text: a valid file mutated (:func:`_mutate`), or random JSON."""
    if draw(st.integers(0, 7)) == 0:
        return json.dumps(draw(JSON))
    d = _valid_params()
    draw(_mutate(d, _PARAMS_KEYS, JSON))
    return json.dumps(d)


@pytest.fixture(scope="module")
def photo(tmp_path_factory) -> Path:
    from jkatana.io.exr import write_exr

    p = tmp_path_factory.mktemp("photo") / "photo.exr"
    write_exr(p, {"Y": np.tile(np.linspace(0.1, 1.0, 64), (16, 1))})
    return p


def _check_params_file(text: str, folder: Path, photo: Path, capsys) -> None:
    from jkatana.fit.params import read_params
    from jkatana.maps.reflectance_map import read_map

    p = folder / "h.json"
    p.write_text(text)
    out = folder / "m.exr"
    out.unlink(missing_ok=True)
    rc = main(["map", str(photo), "-o", str(out), "--resolution", "4", "16", "--hiraji", str(p)])
    _, err = capsys.readouterr()
    assert rc in (0, 2), (rc, err)
    if rc == 2:
        assert len([ln for ln in err.splitlines() if ln.strip()]) == 1 and "Traceback" not in err, err
        assert not out.exists()
    else:
        m = read_map(out)
        for ch in (m.w, m.mu0, m.chi, m.mu1, m.beta):
            assert np.isfinite(np.asarray(ch)).all()
        assert (np.asarray(m.mu0) > 0).all() and (np.asarray(m.chi) > 0).all()
    try:
        params = read_params(p)
    except InputError as err:
        _one_line(err)
        return
    assert math.isfinite(params.scale) and params.scale > 0 and math.isfinite(params.mu) and params.mu > 0
    _check_material(p, folder)


def _check_material(params_path: Path, folder: Path) -> None:
    """The renderer's material with the parameter file as its hiraji: finite maps and scales, or one line."""
    from jkatana.render.renderer import load_geometry, load_material
    from jkatana.render.scenefile import scene_from_dict

    raw = tomllib.loads(sphere_scene(8, 8, 1, spectral=GRID))
    raw["material"]["hiraji"] = str(params_path)
    scene = scene_from_dict(raw, folder / "scene.toml")
    try:
        maps, chi, beta, _ = load_material(scene, load_geometry(scene))
    except InputError as err:
        _one_line(err)
        return
    assert np.isfinite(maps).all() and math.isfinite(chi) and chi > 0 and math.isfinite(beta) and beta > 0


@EVERYDAY
@given(params_documents())
def test_parameter_files_accepted_with_finite_results_or_refused_in_one_line(photo, tmp_path_factory, capsys, text):
    _check_params_file(text, tmp_path_factory.mktemp("p"), photo, capsys)


@pytest.mark.slow
@MANY
@given(params_documents())
def test_parameter_files_many(photo, tmp_path_factory, capsys, text):
    _check_params_file(text, tmp_path_factory.mktemp("p"), photo, capsys)


# ---------------------------------------------------------------- scenes

#: Keys a scene may hold beyond those of the test sphere (drawn as well, so optional fields are tried).
_EXTRA_KEYS = {
    "material": ["map", "hiraji", "calibration", "optical_constants"],
    "environment": ["scale", "rotation_deg", "turbidity", "albedo", "elevation_deg", "radiance", "sun"],
    "camera": ["roll_deg", "azimuth_deg", "position", "up"],
    "render": ["mode", "rank", "seed", "split_sun", "env_window"],
    "spectral": ["start", "stop", "step"],
    "film": ["exposure", "transfer", "colourspace"],
    "geometry": ["sphere"], "output": ["name"],
}


@st.composite
def scene_documents(draw):
    """The test sphere's scene mutated (:func:`_mutate`: numbers, fields, sections), as TOML text."""
    raw = tomllib.loads(sphere_scene(8, 8, 1, spectral=GRID))
    draw(_mutate(raw, _EXTRA_KEYS, TOML))
    return tomli_w.dumps(raw)


def _small(scene) -> bool:
    """Small enough to render in the everyday suite (a few seconds once compiled)."""
    w, h = scene.camera.resolution
    env = scene.environment
    return (w * h <= 32 * 32 and scene.render.samples <= 4 and scene.spectral.grid.size <= 31
            and (getattr(env, "resolution", None) is None or env.resolution[0] * env.resolution[1] <= 64 * 128))


def _check_scene(text: str, folder: Path) -> None:
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scenefile import load_scene

    p = folder / "scene.toml"
    p.write_text(text)
    try:
        scene = load_scene(p)
        if not _small(scene):
            return
        frame = render_view(prepare(scene))
    except InputError as err:
        _one_line(err)
        return
    assert np.isfinite(np.asarray(frame.xyz)).all()


@EVERYDAY
@given(scene_documents())
def test_scenes_accepted_and_rendered_finite_or_refused_in_one_line(tmp_path_factory, text):
    _check_scene(text, tmp_path_factory.mktemp("s"))


@pytest.mark.slow
@MANY
@given(scene_documents())
def test_scenes_many(tmp_path_factory, text):
    _check_scene(text, tmp_path_factory.mktemp("s"))

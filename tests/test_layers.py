"""jkatana's packages form layers: a package imports only from layers below its own, and packages never import
each other in a circle. Every ``import`` of ``jkatana/`` is read with :mod:`ast`, at module level and inside
functions alike (an import deferred into a function still ties the two packages together).

The layers, lowest first (a package may import any package of a lower layer, none of a higher one, and one of
its own layer only where :data:`SAME_LAYER` allows it, in one direction):

0. ``errors`` — the error classes
1. ``runtime``, ``shared`` — the runtime setup, where shared data lives
2. ``spectral``, ``io`` — wavelength grids and colorimetry; files
3. ``models`` — the reflectance models (lobes, Fresnel, microfacets, the fitted models' parameters)
4. ``measure``, ``light``, ``shape``, ``brdf`` — measurements, environments, geometry, BRDF tables
5. ``fit``, ``maps`` — fitting the models to measurements, reflectance maps
6. ``render`` — the reference renderer
7. ``interactive``, ``export`` — the GL viewer; scenes and BRDFs written for other renderers
8. ``cli`` — the command line
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jkatana"

#: The layers, lowest first.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors",),
    ("runtime", "shared"),
    ("spectral", "io"),
    ("models",),
    ("measure", "light", "shape", "brdf"),
    ("fit", "maps"),
    ("render",),
    ("interactive", "export"),
    ("cli",),
)

#: Imports between two packages of one layer, allowed in this direction only (the other would be a loop):
#: ``(importing package, imported package)`` and why.
SAME_LAYER: dict[tuple[str, str], str] = {
    ("brdf", "measure"): "BRDF tables are sliced and written at the measurement protocol's geometry "
                         "(measure.protocol, measure.table), weighted by its camera (measure.camera, measure.setup) "
                         "and drawn with its noise model (measure.noise)",
}

#: Imports allowed against the layers, each with its reason: ``(importing module, imported module)``.
EXCEPTIONS: dict[tuple[str, str], str] = {}


def _level() -> dict[str, int]:
    return {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """``(imported jkatana module, line)`` of every import in ``path``, relative imports resolved."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.split(".")[0] == "jkatana"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.split(".")[0] == "jkatana":
                # ``from jkatana.fit import region`` names the module jkatana.fit.region; ``from jkatana.fit import
                # x`` of a name x the package jkatana.fit
                out += [(f"{name}.{a.name}" if name == "jkatana" or _is_module(f"{name}.{a.name}") else name,
                         node.lineno)
                        for a in node.names]
    return out


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _package(module: str) -> str:
    """The layered unit of ``jkatana.a.b``: ``a`` (a subpackage or a top-level module such as ``errors``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def package_imports() -> list[tuple[str, str, str, str, int]]:
    """``(package, imported package, importing module, imported module, line)`` of every import between
    two different packages of ``jkatana``."""
    edges = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        for imported, line in _imports(path):
            a, b = _package(module), _package(imported)
            if a and b and a != b:
                edges.append((a, b, module, imported, line))
    return edges


def violations(edges=None) -> list[str]:
    """Every import that runs up the layers or across one, and every package not in :data:`LAYERS`."""
    level = _level()
    edges = package_imports() if edges is None else edges
    bad = []
    for a, b, module, imported, line in edges:
        for pkg in (a, b):
            if pkg not in level:
                bad.append(f"{module}:{line}: package {pkg!r} has no layer (add it to tests/test_layers.py LAYERS)")
        if a not in level or b not in level or (module, imported) in EXCEPTIONS:
            continue
        if level[b] > level[a]:
            bad.append(f"{module}:{line} imports {imported} ({b!r} is in a higher layer than {a!r})")
        elif level[b] == level[a] and (a, b) not in SAME_LAYER:
            bad.append(f"{module}:{line} imports {imported} ({b!r} is in the layer of {a!r})")
    return sorted(set(bad))


def cycles(edges=None) -> list[list[str]]:
    """The package-level import cycles (strongly connected components of more than one package, Tarjan 1972)."""
    edges = package_imports() if edges is None else edges
    graph: dict[str, set[str]] = {}
    for a, b, *_ in edges:
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


#: Import cycles between the modules of one package allowed, and why.
MODULE_CYCLES: dict[tuple[str, ...], str] = {
    ("jkatana.render.scene", "jkatana.render.scenefile"):
        "scene.py names the reader's load_scene etc. for its callers through a PEP 562 __getattr__, imported on "
        "first use; the scene module itself never imports the reader at load time",
}


def module_cycles() -> list[tuple[str, ...]]:
    """The import cycles between modules of ``jkatana`` (an import of a package counts as one of its
    ``__init__``; a module importing its own package's ``__init__`` is left out, as Python runs that first)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    edges = []
    for module, path in modules.items():
        for imported, line in _imports(path):
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            if imported and imported != module and not module.startswith(imported + "."):
                edges.append((module, imported, module, imported, line))
    return [tuple(c) for c in cycles(edges)]


def test_the_parser_sees_every_kind_of_import(tmp_path):
    """Module-level, function-level, ``from`` and relative imports are all read, a module imported by
    ``from package import module`` as that module."""
    sub = tmp_path / "jkatana" / "render"
    sub.mkdir(parents=True)
    (tmp_path / "jkatana" / "interactive").mkdir()
    (tmp_path / "jkatana" / "interactive" / "viewer.py").write_text("")
    (sub / "plan.py").write_text("")
    (sub / "x.py").write_text("import jkatana.light.envmap\nfrom jkatana.models import lobes\n"
                              "def f():\n    from ..interactive import viewer\n    from . import plan\n"
                              "    from jkatana import fit\n")
    global PACKAGE
    saved, PACKAGE = PACKAGE, tmp_path / "jkatana"
    try:
        got = sorted(_imports(sub / "x.py"))
    finally:
        PACKAGE = saved
    assert got == [("jkatana.fit", 6), ("jkatana.interactive.viewer", 4), ("jkatana.light.envmap", 1),
                   ("jkatana.models", 2), ("jkatana.render.plan", 5)]


def test_the_check_fails_on_an_upward_import_and_a_loop():
    edges = [("light", "render", "jkatana.light.x", "jkatana.render.y", 3),
             ("render", "light", "jkatana.render.y", "jkatana.light.x", 5)]
    assert violations(edges) == ["jkatana.light.x:3 imports jkatana.render.y ('render' is in a higher layer than 'light')"]
    assert cycles(edges) == [["light", "render"]]


def test_every_package_has_a_layer():
    top = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
           if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").exists()}
    assert top - set(_level()) == set(), "packages without a layer: add them to LAYERS"


def test_no_import_runs_up_the_layers():
    bad = violations()
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_no_import_cycle_between_packages():
    assert cycles() == []


def test_no_import_cycle_between_modules():
    found = set(module_cycles())
    assert found - set(MODULE_CYCLES) == set(), "module import cycles:\n" + "\n".join(map(str, found))
    assert set(MODULE_CYCLES) <= found, "a listed module cycle is gone: remove it from MODULE_CYCLES"


def test_each_exception_is_still_needed_and_explained():
    edges = package_imports()
    for (a, b), reason in SAME_LAYER.items():
        assert reason.strip() and _level()[a] == _level()[b], (a, b)
        assert any(e[:2] == (a, b) for e in edges), f"{a} no longer imports {b}: remove it from SAME_LAYER"
    present = {(m, i) for *_, m, i, _ in edges}
    for (module, imported), reason in EXCEPTIONS.items():
        assert reason.strip(), f"{module} -> {imported}: say why it is allowed"
        assert (module, imported) in present, f"{module} no longer imports {imported}: remove the exception"

"""Optical constants n(λ) + i k(λ) from refractiveindex.info YAML files.

Reads the database format of refractiveindex.info (M. N. Polyanskiy, 2024,
"Refractiveindex.info database of optical constants", Sci. Data 11, 94;
the database is CC0 1.0). Supported ``DATA`` types: ``tabulated nk``,
``tabulated n``, ``tabulated k`` and the dispersion formulas 1 (Sellmeier),
2 (Sellmeier, squared poles), 3 (polynomial) and 5 (Cauchy). Wavelengths in
the files are micrometres; jkatana works in nanometres.

Shipped with the package (``jkatana/data/optical_constants``, CC0, licence
text beside the files; ``README.md`` there lists every table with its full
reference), named ``<material>-<source>`` and selectable by that name:

- iron ``Fe-Johnson`` (the default), ``Fe-Querry``, ``Fe-Werner``, ``Fe-Werner-DFT``;
  chromium ``Cr-Johnson``, ``Cr-Rakic-BB``, ``Cr-Rakic-LD``, ``Cr-Sytchkova``;
  nickel ``Ni-Johnson``, ``Ni-Rakic-BB``, ``Ni-Rakic-LD``, ``Ni-Werner``, ``Ni-Werner-DFT``;
  molybdenum ``Mo-Kirillova``, ``Mo-Querry``, ``Mo-Werner``, ``Mo-Werner-DFT``;
  tungsten ``W-Rakic-BB``, ``W-Rakic-LD``, ``W-Werner``, ``W-Werner-DFT``;
  magnetite ``Fe3O4-Querry``;
  stainless steel ``SS-Karlsson-austenitic``, ``SS-Karlsson-ferritic``.
- Sources: P. B. Johnson and R. W. Christy (1974), Phys. Rev. B 9, 5056–5070;
  M. R. Querry (1985), Contractor Report CRDC-CR-85034, and (1987)
  CRDEC-CR-88009 (Mo); W. S. M. Werner, K. Glantschnig, C. Ambrosch-Draxl
  (2009), J. Phys. Chem. Ref. Data 38, 1013–1092 (measured and DFT);
  A. D. Rakić, A. B. Djurišić, J. M. Elazar, M. L. Majewski (1998), Appl. Opt.
  37, 5271–5283 (Brendel–Bormann and Lorentz–Drude fits); A. Sytchkova et al.
  (2021), Opt. Mater. 121, 111530; M. M. Kirillova, L. V. Nomerovannaya,
  M. M. Noskov (1971), Sov. Phys. JETP 33, 1210–1214; B. Karlsson and
  C. G. Ribbing (1982), J. Appl. Phys. 53, 6340–6346.

Only tables covering 380–780 nm with one value per wavelength are shipped
(the database's Ordal and Windt tables of these metals do not reach the
visible; its Fe2O3 Querry and W Weaver tables repeat wavelengths).
"""

from __future__ import annotations

import dataclasses
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from jkatana.errors import InputError
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid, resample

_DATA = resources.files("jkatana") / "data" / "optical_constants"


def _shipped() -> dict[str, str]:
    out = {}
    for material in sorted(_DATA.iterdir(), key=lambda p: p.name):
        if material.is_dir():
            for f in sorted(material.iterdir(), key=lambda p: p.name):
                if f.name.endswith(".yml"):
                    out[f"{material.name}-{f.name[:-4]}"] = f"{material.name}/{f.name}"
    return out


#: Shipped tables, by name ``<material>-<source>`` → path inside the package data.
SHIPPED = _shipped()
#: Aliases accepted by :func:`load` (lower case).
ALIASES = {"johnson": "Fe-Johnson", "querry": "Fe-Querry", "iron": "Fe-Johnson",
           "fe": "Fe-Johnson", "johnson1974": "Fe-Johnson", "querry1985": "Fe-Querry",
           "chromium": "Cr-Johnson", "cr": "Cr-Johnson", "nickel": "Ni-Johnson", "ni": "Ni-Johnson",
           "molybdenum": "Mo-Kirillova", "mo": "Mo-Kirillova", "tungsten": "W-Rakic-LD", "w": "W-Rakic-LD",
           "stainless": "SS-Karlsson-austenitic", "stainless-steel": "SS-Karlsson-austenitic",
           "ss": "SS-Karlsson-austenitic"} | {name.lower(): name for name in SHIPPED}

@dataclasses.dataclass(frozen=True)
class OpticalTable:
    """Tabulated optical constants as read from a file (wavelength in nm)."""

    wavelengths: np.ndarray
    n: np.ndarray
    k: np.ndarray
    source: str
    reference: str = ""

    def on_grid(self, grid: WavelengthGrid = DEFAULT_GRID, *, extrapolate: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
        """``(n, k)`` linearly interpolated onto ``grid``; refuses to extrapolate by default."""
        nk = resample(self.wavelengths, np.stack([self.n, self.k]), grid,
                      extrapolate=extrapolate, name=self.source)
        return nk[0], nk[1]


def _formula(kind: int, coeffs: np.ndarray, wl_um: np.ndarray, path) -> np.ndarray:
    c = coeffs
    if kind == 1:  # Sellmeier: n^2 - 1 = C0 + sum Bi λ² / (λ² - Ci²)
        n2 = 1.0 + c[0] + sum(c[i] * wl_um**2 / (wl_um**2 - c[i + 1] ** 2) for i in range(1, len(c) - 1, 2))
        return np.sqrt(n2)
    if kind == 2:  # Sellmeier-2: n^2 - 1 = C0 + sum Bi λ² / (λ² - Ci)
        n2 = 1.0 + c[0] + sum(c[i] * wl_um**2 / (wl_um**2 - c[i + 1]) for i in range(1, len(c) - 1, 2))
        return np.sqrt(n2)
    if kind == 3:  # polynomial: n^2 = C0 + sum Ci λ^Ci+1
        n2 = c[0] + sum(c[i] * wl_um ** c[i + 1] for i in range(1, len(c) - 1, 2))
        return np.sqrt(n2)
    if kind == 5:  # Cauchy: n = C0 + sum Ci λ^Ci+1
        return c[0] + sum(c[i] * wl_um ** c[i + 1] for i in range(1, len(c) - 1, 2))
    raise InputError(f"refractiveindex.info formula {kind} is not supported", path=path, field="DATA")


def read_yaml(path: str | Path, *, formula_samples: int = 401) -> OpticalTable:
    """Read a refractiveindex.info YAML file into an :class:`OpticalTable`.

    Formula entries are sampled on ``formula_samples`` wavelengths over their
    ``wavelength_range``. A material given only by ``n`` gets ``k = 0`` over
    the same range (and vice versa for ``tabulated k`` alone, which is an error
    since ``n`` is then unknown).
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except UnicodeDecodeError:
        raise InputError("not UTF-8 text (a YAML file is)", path=path) from None
    except yaml.YAMLError as err:  # one line: the problem and where, not PyYAML's multi-line excerpt
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise InputError(f"not valid YAML ({getattr(err, 'problem', None) or type(err).__name__}{where})",
                         path=path) from None
    if not isinstance(doc, dict) or "DATA" not in doc:
        raise InputError("no DATA section (not a refractiveindex.info file?)", path=path)
    n_part = k_part = None
    for i, entry in enumerate(doc["DATA"]):
        kind = str(entry.get("type", "")).strip()
        try:
            if kind.startswith("tabulated"):
                rows = np.array([[float(v) for v in line.split()]
                                 for line in str(entry["data"]).strip().splitlines() if line.strip()])
                wl = rows[:, 0] * 1000.0
                if kind == "tabulated nk":
                    n_part, k_part = (wl, rows[:, 1]), (wl, rows[:, 2])
                elif kind == "tabulated n":
                    n_part = (wl, rows[:, 1])
                elif kind == "tabulated k":
                    k_part = (wl, rows[:, 1])
                else:
                    raise InputError(f"unknown type {kind!r}", path=path, field=f"DATA[{i}].type")
            elif kind.startswith("formula"):
                number = int(kind.split()[1])
                lo, hi = (float(v) for v in str(entry["wavelength_range"]).split())
                coeffs = np.array([float(v) for v in str(entry["coefficients"]).split()])
                wl_um = np.linspace(lo, hi, formula_samples)
                n_part = (wl_um * 1000.0, _formula(number, coeffs, wl_um, path))
            else:
                raise InputError(f"unknown type {kind!r}", path=path, field=f"DATA[{i}].type")
        except (KeyError, ValueError, IndexError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError(f"malformed entry: {err}", path=path, field=f"DATA[{i}]") from None
    if n_part is None:
        raise InputError("no refractive index n in file", path=path, field="DATA")
    wl = n_part[0]
    n = n_part[1]
    if k_part is None:
        k = np.zeros_like(n)
    else:
        lo, hi = max(wl[0], k_part[0][0]), min(wl[-1], k_part[0][-1])
        keep = (wl >= lo) & (wl <= hi)
        wl, n = wl[keep], n[keep]
        k = np.interp(wl, k_part[0], k_part[1])
    if np.any(~np.isfinite(n)) or np.any(~np.isfinite(k)) or np.any(n <= 0) or np.any(k < 0):
        raise InputError("n must be finite and > 0, k finite and >= 0", path=path, field="DATA")
    refs = str(doc.get("REFERENCES", "")).strip()
    return OpticalTable(wl, n, k, source=str(path.name if path.parent.name in ("", ".") else path), reference=refs)


def shipped_path(name: str) -> Path:
    """Path of a shipped table by name (see :data:`SHIPPED`, :data:`ALIASES`)."""
    key = ALIASES.get(name.lower(), name)
    if key not in SHIPPED:
        raise InputError(f"unknown optical-constant table {name!r}; shipped: {sorted(SHIPPED)}",
                         field="optical_constants")
    return Path(str(_DATA / SHIPPED[key]))


def load(name_or_path: str | Path = "Fe-Johnson") -> OpticalTable:
    """Load a shipped table by name (``"Fe-Johnson"``, ``"querry"``, …) or a YAML file by path."""
    p = Path(name_or_path)
    if p.suffix.lower() in (".yml", ".yaml"):
        table = read_yaml(p)
    else:
        key = ALIASES.get(str(name_or_path).lower(), str(name_or_path))
        table = read_yaml(shipped_path(key))
        table = dataclasses.replace(table, source=key)
    return table


def iron(source: str = "johnson", grid: WavelengthGrid = DEFAULT_GRID) -> tuple[np.ndarray, np.ndarray]:
    """Iron's ``(n, k)`` on ``grid`` from Johnson & Christy 1974 (default) or Querry 1985."""
    return load(source).on_grid(grid)

"""Units of the parameters: what the fsi model reads, and conversions between units.

A parameter's ``unit`` is the unit of every number written for it (prior, bounds,
ground truth) and of every number reported for it. For the fsi model the value is
set into the model's configuration at the parameter's ``target``, which the model
reads in one fixed unit (:func:`fsi_target_unit`: Pa for the Young's moduli,
mm^2/s for the inflow rate, mm^3/s in the 3D model, ...). :func:`validate_fsi_units`
refuses a parameter whose
unit is another one, so that a prior written in kPa is never read as Pa; where the
unit converts into the target's, the error gives the parameter's numbers in the
target's unit, ready to paste. For the python and command models the unit is a
free label (their functions and templates read the numbers as they are).

Units are products of powers of the base units below, written with ``*``, ``.``,
``·`` or a space between factors, ``/`` before the factors of the denominator and
``^n`` (or a trailing digit, ``mm2``; or ``²``, ``³``) for powers: ``Pa``, ``kPa``,
``mm^2/s``, ``um2/s``, ``mm/Pa``, ``kg/m^3``, ``Pa s``. ``-``, ``1`` and the empty
string are dimensionless. Prefixes are case-sensitive (``mPa`` is a milli-pascal,
``MPa`` a mega-pascal).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

from bayescalib.config import ConfigError

__all__ = [
    "DIMENSIONLESS",
    "UnitError",
    "conversion_factor",
    "fsi_target_unit",
    "parse_unit",
    "validate_fsi_units",
]

#: spellings of "no unit"
DIMENSIONLESS = ("-", "", "1")

# base unit -> (SI factor, dimension exponents (m, kg, s))
_LENGTH = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "nm": 1e-9}
_PRESSURE = {"Pa": 1.0, "mPa": 1e-3, "hPa": 1e2, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9}
_MASS = {"kg": 1.0, "g": 1e-3, "mg": 1e-6}
_TIME = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
_BASE: dict[str, tuple[float, tuple[int, int, int]]] = {
    **{u: (f, (1, 0, 0)) for u, f in _LENGTH.items()},
    **{u: (f, (-1, 1, -2)) for u, f in _PRESSURE.items()},
    **{u: (f, (0, 1, 0)) for u, f in _MASS.items()},
    **{u: (f, (0, 0, 1)) for u, f in _TIME.items()},
    "N": (1.0, (1, 1, -2)),
    "mN": (1e-3, (1, 1, -2)),
    "uN": (1e-6, (1, 1, -2)),
    "l": (1e-3, (3, 0, 0)),
    "L": (1e-3, (3, 0, 0)),
    "ml": (1e-6, (3, 0, 0)),
    "mL": (1e-6, (3, 0, 0)),
}
_FACTOR = re.compile(r"^([A-Za-z]+)(?:\^?(-?\d+))?$")

#: fsi targets read in a fixed unit (the keys of fsi.schema.yaml: "User units:
#: lengths mm, stresses Pa, inflow rate mm^2/s, density kg/m^3, viscosity Pa s");
#: the physics candidates' phi come from bayescalib.models.fsi.physics.CANDIDATES
_FSI_UNITS: dict[str, str] = {
    "material.E": "Pa",
    "material.nu": "-",
    "inflow.rate": "mm^2/s",
    "fluid.density": "kg/m^3",
    "fluid.viscosity": "Pa s",
    "geometry.length": "mm",
    "geometry.channel_height": "mm",
    "geometry.width": "mm",
    "geometry.height": "mm",
    "geometry.centre": "mm",
}
#: what the 3D model (geometry.dim 3) reads differently, and its own geometry keys
_FSI_UNITS_3D: dict[str, str] = {
    "inflow.rate": "mm^3/s",
    "geometry.channel_width": "mm",
    "geometry.depth": "mm",
    "geometry.centre_z": "mm",
}
_SUBDOMAIN = re.compile(r"^material\.subdomains\.[A-Za-z_]\w*\.(E|nu)$")
_PHI = re.compile(r"^physics\.([A-Za-z_]\w*)\.phi$")


class UnitError(ValueError):
    """A unit that cannot be read."""


def parse_unit(unit: str) -> tuple[float, tuple[int, int, int]]:
    """The SI factor and the dimension (exponents of m, kg, s) of ``unit``.

    Parameters
    ----------
    unit
        A unit as written in a config, e.g. ``"kPa"``, ``"mm^2/s"``, ``"-"``.

    Returns
    -------
    factor, dimension
        One ``unit`` is ``factor`` SI units of that dimension.

    Raises
    ------
    UnitError
        A factor that is no known unit (the message lists them).
    """
    text = str(unit).strip()
    if text in DIMENSIONLESS:
        return 1.0, (0, 0, 0)
    text = (text.replace("µ", "u").replace("μ", "u").replace("²", "^2").replace("³", "^3")
            .replace("·", " ").replace("*", " ").replace(".", " "))
    factor, dim = 1.0, [0, 0, 0]
    for k, part in enumerate(text.split("/")):
        if k > 1:
            raise UnitError(f"unit '{unit}' has more than one '/'")
        sign = -1 if k else 1
        words = part.split()
        if not words and k == 0 and "/" in text:  # "1/s"
            continue
        for word in words:
            if word == "1":
                continue
            m = _FACTOR.match(word)
            if m is None or m.group(1) not in _BASE:
                raise UnitError(
                    f"unknown unit '{word}' in '{unit}' (known: "
                    f"{', '.join(sorted(_BASE, key=str.lower))}, with powers like mm^2)")
            f, d = _BASE[m.group(1)]
            p = sign * int(m.group(2) or 1)
            factor *= f ** p
            dim = [a + p * b for a, b in zip(dim, d, strict=True)]
    return factor, (dim[0], dim[1], dim[2])


def conversion_factor(unit: str, to: str) -> float | None:
    """Number by which a value in ``unit`` is multiplied to be in ``to``; None when
    the two are of different dimensions or one cannot be read."""
    try:
        f_from, d_from = parse_unit(unit)
        f_to, d_to = parse_unit(to)
    except UnitError:
        return None
    if d_from != d_to:
        return None
    return f_from / f_to


def fsi_target_unit(target: str, dim: int = 2) -> str | None:
    """Unit in which the fsi model reads the value of ``target`` (a dotted key of
    ``forward_model.fsi``); None for a key outside the table (not checked). ``dim``: the
    model's ``geometry.dim`` (the 3D model's inflow rate is a volume rate, mm^3/s)."""
    if dim == 3 and target in _FSI_UNITS_3D:
        return _FSI_UNITS_3D[target]
    if target in _FSI_UNITS:
        return _FSI_UNITS[target]
    m = _SUBDOMAIN.match(target)
    if m:
        return _FSI_UNITS[f"material.{m.group(1)}"]
    m = _PHI.match(target)
    if m:
        from bayescalib.models.fsi.physics import CANDIDATES

        cand = CANDIDATES.get(m.group(1))
        return None if cand is None else cand.unit
    return None


def _same(unit: str, target_unit: str) -> bool:
    """Whether ``unit`` is ``target_unit`` however spelled (``mm2/s``, ``mm^2/s``)."""
    c = conversion_factor(unit, target_unit)
    return c is not None and math.isclose(c, 1.0, rel_tol=1e-12)


def _num(x: float) -> str:
    return f"{x:.10g}"


def _converted(par: Mapping[str, Any], unit: str, c: float) -> str:
    """The parameter's entry with its numbers in ``unit`` (``c`` times the old ones),
    as a one-line YAML mapping."""
    prior = dict(par["prior"])
    out_prior = [f"type: {prior['type']}"]
    for key in ("lo", "hi", "mu", "sigma", "a", "b"):
        if prior.get(key) is None:
            continue
        v = float(prior[key])
        if key in ("lo", "hi") or (key in ("mu", "sigma") and prior["type"] == "normal"):
            v *= c
        elif key == "mu":  # lognormal: mu of log(x) moves by log(c), sigma stays
            v += math.log(c)
        out_prior.append(f"{key}: {_num(v)}")
    parts = [f"name: {par['name']}", f"unit: {unit if unit not in ('', '-') else repr('-')}"]
    parts.append(f"target: {par['target']}")
    parts.append("prior: {" + ", ".join(out_prior) + "}")
    if par.get("bounds") is not None:
        parts.append(f"bounds: [{', '.join(_num(c * float(b)) for b in par['bounds'])}]")
    if par.get("uncertain"):
        parts.append("uncertain: true")
    if par.get("ground_truth") is not None:
        parts.append(f"ground_truth: {_num(c * float(par['ground_truth']))}")
    return "{" + ", ".join(parts) + "}"


def validate_fsi_units(parameters: Sequence[Mapping[str, Any]], where: str = "config",
                       dim: int = 2) -> None:
    """Refuse a parameter whose unit is not the unit the fsi model reads its target in.

    Parameters
    ----------
    parameters
        The study's ``parameters`` section (validated, every ``target`` filled).
    where
        Name of the configuration's source for the message.
    dim
        The fsi model's ``geometry.dim`` (2 or 3).

    Raises
    ------
    ConfigError
        Naming ``parameters[k].unit``, its value, the target and the target's unit;
        when the unit converts into the target's, the parameter's entry with its
        prior, bounds and ground truth converted (to paste in place of the old one).
    """
    for k, par in enumerate(parameters):
        target = par["target"]
        want = fsi_target_unit(target, dim)
        unit = str(par["unit"])
        if want is None or _same(unit, want):
            continue
        none = want in DIMENSIONLESS
        msg = (f"{where}: parameters[{k}].unit: '{unit}' for parameter '{par['name']}', but "
               f"the fsi model reads its target {target} "
               + ("as a dimensionless number (unit '-', '1' or '')" if none else f"in {want}"))
        if unit == "-":
            msg += " ('-' is also the unit of a parameter that names none)"
        c = conversion_factor(unit, want)
        if c is not None:
            msg += (f". In {want} (x {_num(c)}), the parameter reads: "
                    f"{_converted(par, want, c)}")
        elif none:
            msg += ": write unit: '-' and its prior, bounds and ground_truth as plain numbers"
        else:
            msg += f": write unit: {want} and its prior, bounds and ground_truth in {want}"
        raise ConfigError(msg)

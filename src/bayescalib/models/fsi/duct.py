"""Fully developed laminar flow in a rectangular duct (the 3D model's inflow profile).

For a duct ``0 <= y <= H``, ``0 <= z <= W`` with no-slip walls and a constant pressure
gradient ``G = -dp/dx``, the axial velocity solves ``mu (u_yy + u_zz) = -G`` with
``u = 0`` on the walls. Expanding in ``sin(n pi y / H)`` (odd ``n``; the sine series
of ``y (H - y) / 2`` has the coefficients ``4 H^2 / (pi^3 n^3)``) gives the classical
series (White, *Viscous Fluid Flow*, 3rd ed., Sec. 3-3.3, eq. 3-48, in shifted
coordinates)

    u(y, z) = (G / mu) sum_{n odd} 4 H^2 / (pi^3 n^3) sin(n pi y / H)
              [1 - cosh(n pi (z - W/2) / H) / cosh(n pi W / (2 H))],

and integrating over the section, the volume rate

    Q = (G / mu) sum_{n odd} 8 H^3 / (pi^4 n^4) [W - (2 H / (n pi)) tanh(n pi W / (2 H))]

(``W -> infinity``: ``Q / W = G H^3 / (12 mu)``, plane Poiseuille flow). The
hyperbolic ratio is evaluated as ``(exp(k (z - W)) + exp(-k z)) / (1 + exp(-k W))``,
``k = n pi / H``, whose exponents are never positive inside the duct (no overflow).
The sine terms decay like ``n^-3``: with :data:`DUCT_TERMS` odd terms the velocity's
truncation error is below 2e-5 of the centreline velocity.

The same functions serve NumPy arrays (the analytic reference of the tests and the
benchmark) and NGSolve coefficient functions (the 3D model's inflow): ``lib`` supplies
``sin`` and ``exp``.
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import numpy as np

__all__ = ["DUCT_TERMS", "duct_flow_rate", "duct_flux_per_width", "duct_velocity"]

#: odd terms n = 1, 3, ..., 2 DUCT_TERMS - 1 of the series
DUCT_TERMS = 40


def duct_velocity(y: Any, z: Any, H: float, W: float, *, terms: int = DUCT_TERMS,
                  lib: ModuleType = np) -> Any:
    """Axial velocity of the developed duct flow per unit ``G / mu``.

    Parameters
    ----------
    y, z
        Coordinates (mm): NumPy arrays of one shape, or NGSolve coefficient functions
        (``ngsolve.y``, ``ngsolve.z``) with ``lib=ngsolve``.
    H, W : float
        Duct height (y) and width (z), mm.
    terms : int
        Odd terms of the series.
    lib : module
        Provides ``sin`` and ``exp`` (``numpy`` or ``ngsolve``).

    Returns
    -------
    array or CoefficientFunction
        ``u mu / G`` in mm^2 (multiply by ``G / mu`` in 1/(mm s) for mm/s).
    """
    out = 0.0
    for j in range(terms):
        n = 2 * j + 1
        k = n * math.pi / H
        ratio = (lib.exp(k * (z - W)) + lib.exp(-k * z)) / (1.0 + math.exp(-k * W))
        out = out + 4.0 * H**2 / (math.pi**3 * n**3) * lib.sin(k * y) * (1.0 - ratio)
    return out


def duct_flow_rate(H: float, W: float, *, terms: int = DUCT_TERMS) -> float:
    """Volume rate of :func:`duct_velocity` per unit ``G / mu`` (mm^4).

    Parameters
    ----------
    H, W : float
        Duct height and width, mm.
    terms : int
        Odd terms of the series (the terms decay like ``n^-4``).

    Returns
    -------
    float
        ``Q mu / G``, mm^4; ``Q = duct_flow_rate * G / mu``.
    """
    total = 0.0
    for j in range(terms):
        n = 2 * j + 1
        total += 8.0 * H**3 / (math.pi**4 * n**4) * (
            W - 2.0 * H / (n * math.pi) * math.tanh(n * math.pi * W / (2.0 * H)))
    return total


def duct_flux_per_width(z: Any, H: float, W: float, *, terms: int = DUCT_TERMS) -> Any:
    """Volume rate per unit width through the line ``z`` of the section, per unit ``G / mu``.

    ``q(z) = int_0^H u(y, z) dy`` of :func:`duct_velocity` (each sine term integrates to
    ``2 H / (n pi)``): the flux of a 2D channel that sees the duct's velocity profile at
    ``z``; ``sum(q) dz`` over the width is :func:`duct_flow_rate`.

    Parameters
    ----------
    z : float or array
        Position across the duct, ``0 <= z <= W``, mm.
    H, W : float
        Duct height and width, mm.
    terms : int
        Odd terms of the series.

    Returns
    -------
    float or array
        ``q mu / G``, mm^3 (``q = duct_flux_per_width * G / mu`` in mm^2/s).
    """
    z = np.asarray(z, dtype=float)
    out = np.zeros_like(z)
    for j in range(terms):
        n = 2 * j + 1
        k = n * math.pi / H
        ratio = (np.exp(k * (z - W)) + np.exp(-k * z)) / (1.0 + math.exp(-k * W))
        out = out + 8.0 * H**3 / (math.pi**4 * n**4) * (1.0 - ratio)
    return float(out) if out.ndim == 0 else out

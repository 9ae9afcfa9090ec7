"""Hyperelastic laws of the solid (paper App. B.2), as NGSolve coefficient functions.

The solid is described in the reference configuration by the first Piola–Kirchhoff
stress ``P = F S`` with the deformation gradient ``F = I + grad d``. Two laws are
available, in plane strain for a 2D problem (the 2D deformation gradient with
``F_33 = 1``: the out-of-plane entries ``C_33 = 1``, ``E_33 = 0`` enter the traces
below as constants) and in full 3D for a 3D one (``F`` a 3 x 3 tensor; the same
formulas with no out-of-plane constants). One implementation serves both: the
dimension is read from the shape of ``F``. So do the candidate physics of the solid
(:mod:`bayescalib.models.fsi.physics`): the growth ``F_g = g I_3`` is the same in
both (in plane strain ``F_e,33 = 1/g`` enters as the constant ``C_e,33 = g^-2``; in
3D ``F_e = F / g`` whole, ``J_e = det F / g^3``), and the energy ``g^3 W(F_e)``
gives ``P = g F S_e`` in both; the stiffening factor uses the law's ``W`` (the 3D
energy, or the plane-strain one with its out-of-plane constants).

* ``svk`` — St. Venant–Kirchhoff (the paper's model):
  ``S = lambda tr(E) I + 2 mu E`` with Green–Lagrange strain ``E = (F^T F - I)/2``.
  It is not polyconvex: under strong compression it has a limit point, which is why
  soft parameters (low E) can fail to reach the full load (see NOTES-fsi.md).
* ``neo_hooke`` — compressible neo-Hooke with the energy
  ``W = mu/2 (tr C - 3 - 2 ln J) + lambda/2 (ln J)^2`` (3D trace; in plane strain
  ``tr C = C_11 + C_22 + 1``), giving
  ``S = mu (I - C^-1) + lambda ln J C^-1``. It reduces to the same linear elasticity as
  SVK for small strains.

Lamé parameters from Young's modulus and Poisson's ratio (plane strain uses the 3D
relations): ``lambda = E nu / ((1 + nu)(1 - 2 nu))``, ``mu = E / (2 (1 + nu))``.
``nu = 0.5`` makes ``lambda`` infinite; the solver records such a run as failed before
building anything (:func:`poisson_problem`).
"""

from __future__ import annotations

import math
from typing import Any

LAWS = ("svk", "neo_hooke")


def lame(E: Any, nu: Any) -> tuple[Any, Any]:
    """Lamé parameters ``(lambda, mu)`` from Young's modulus ``E`` and Poisson ratio ``nu``.

    Works with floats and with NGSolve coefficient functions / parameters (same units as
    ``E``; the solver passes E in solver units mg/(mm s^2) = mPa).
    """
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    return lam, mu


def poisson_problem(nu: float) -> str:
    """Return a failure reason if ``nu`` is outside the admissible open range (-1, 0.5), else ``""``."""
    if math.isnan(nu):
        return "Poisson ratio is NaN"
    if nu >= 0.5:
        return (
            f"Poisson ratio nu = {nu} >= 0.5: lambda is infinite (incompressible limit), "
            "not supported by the pure-displacement solid formulation"
        )
    if nu <= -1.0:
        return f"Poisson ratio nu = {nu} <= -1: the elastic energy is not positive"
    return ""


def piola1(law: str, F: Any, E: Any, nu: Any, *, growth: Any = None,
           stiffening: Any = None) -> Any:
    """First Piola–Kirchhoff stress ``P(F)`` of ``law`` as an NGSolve coefficient function.

    Parameters
    ----------
    law
        ``"svk"`` or ``"neo_hooke"``.
    F
        Deformation gradient, a (2, 2) (plane strain) or (3, 3) NGSolve coefficient
        function (dimensionless).
    E, nu
        Young's modulus (solver stress units) and Poisson ratio; floats or NGSolve
        ``Parameter`` objects (so that a compiled form can be reused for new values).
    growth
        Growth strain ``phi`` of an isotropic growth ``F_g = (1 + phi) I_3``
        (:mod:`bayescalib.models.fsi.physics`, candidate 2), or ``None``. With ``phi = 0`` the
        stress is that of the law without growth.
    stiffening
        Fung stiffening parameter ``phi >= 0`` (candidate 5): ``P`` is multiplied by
        ``exp(2 phi W / mu)`` with the law's stored energy ``W``; ``None`` for none.

    Returns
    -------
    CoefficientFunction
        (2, 2) or (3, 3) stress (the shape of ``F``) in the units of ``E``.
    """
    import ngsolve as ng

    lam, mu = lame(E, nu)
    dim = int(F.dims[0])
    plane = dim == 2   # plane strain: the out-of-plane constants C_33, E_33 below
    Id = ng.Id(dim)
    C = F.trans * F
    if law not in LAWS:
        raise ValueError(f"unknown material law '{law}'; expected one of {LAWS}")
    if growth is None:
        g = None
        Ce, c33, lnJ_shift = C, 1.0, 0.0
    else:
        g = 1.0 + growth
        Ce = (1.0 / (g * g)) * C
        c33 = 1.0 / (g * g)
        lnJ_shift = 3.0 * ng.log(g)
    if law == "svk":
        Egl = 0.5 * (Ce - Id)
        if plane:
            e33 = 0.5 * (c33 - 1.0)
            trE = ng.Trace(Egl) + e33
            EE = ng.InnerProduct(Egl, Egl) + e33 * e33
        else:
            trE = ng.Trace(Egl)
            EE = ng.InnerProduct(Egl, Egl)
        S = lam * trE * Id + 2 * mu * Egl
        W = 0.5 * lam * trE * trE + mu * EE
    else:
        Cinv = ng.Inv(Ce)
        lnJ = ng.log(ng.Det(F)) - lnJ_shift
        S = mu * (Id - Cinv) + lam * lnJ * Cinv
        trC = ng.Trace(Ce) + c33 if plane else ng.Trace(Ce)
        W = 0.5 * mu * (trC - 3.0 - 2.0 * lnJ) + 0.5 * lam * lnJ * lnJ
    P = F * S if g is None else g * (F * S)
    if stiffening is not None:
        P = ng.exp(2.0 * stiffening * W / mu) * P
    return P


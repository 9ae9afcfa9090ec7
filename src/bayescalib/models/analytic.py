"""A cheap analytic stand-in for the FSI forward model.

The interface of a half-elliptic biofilm (width ``w``, height ``h``, centred at
``x_c`` on the floor) is displaced by a linear-elastic-like response to the
flow load. With arc-length parameter ``t in [0, pi]`` of the reference
ellipse, ``X(t) = (x_c - w/2 cos t, h sin t)``, the displacement is

.. math::

    u(t) = \\frac{V}{V_0}\\,\\frac{E_0}{E}\\,u_0\\,
           \\Big[(1-\\nu^2)\\,\\phi_s(t) + (1+\\nu)(1-2\\nu)\\,\\phi_c(t)\\Big]

with a shear (downstream bending) mode ``phi_s = (sin^2 t, -0.25 sin 2t)``,
growing with height, and a compression mode ``phi_c = (0, -sin t)``. The two
plane-strain compliance factors make E and nu trade off along a curved band,
like the paper's posterior (SPEC.md: low E goes with low nu), and the
magnitude scales like 1/E and like the inflow rate V, as the FSI model does in
its small-deformation regime (NOTES-fsi.md). ``u_0`` (mm) is the
displacement at the reference load ``V_0`` and stiffness ``E_0``; the default,
0.028 mm at 100 mm^2/s and 400 Pa, matches the FSI model's maximum.

Optional *missing-physics* terms make it a test bed for model-form diagnosis:
``prestrain`` scales the reference shape isotropically about the base centre
(growth/swelling), ``base_slip`` translates the whole interface downstream by
``base_slip * V/V0 * E0/E`` (imperfect attachment).

Use from a study as ``forward_model: {type: python, python: {function:
"bayescalib.models.analytic:interface"}}`` with parameter targets ``E``, ``nu``
and optionally ``V``, ``prestrain``, ``base_slip``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["interface", "reference_interface"]


def reference_interface(n_nodes: int = 66, width: float = 0.6, height: float = 0.4,
                        centre: float = 1.0) -> np.ndarray:
    """Undeformed interface, ordered upstream to downstream.

    Returns
    -------
    ndarray, shape (n_nodes, 2)
        Node coordinates in mm.
    """
    t = np.linspace(0.0, np.pi, n_nodes)
    return np.column_stack([centre - 0.5 * width * np.cos(t), height * np.sin(t)])


def interface(params: Mapping[str, float], *, n_nodes: int = 66, width: float = 0.6,
              height: float = 0.4, centre: float = 1.0, u0: float = 0.028,
              E0: float = 400.0, V0: float = 100.0, fail_below_E: float = 0.0,
              fail_above_load: float = np.inf,
              prestrain_solvable: tuple[float, float] | None = None) -> dict:
    """Deformed interface for parameters ``E`` (Pa), ``nu`` (-), ``V`` (mm^2/s).

    Parameters
    ----------
    params
        Mapping with ``E`` and ``nu``; optional ``V`` (default ``V0``),
        ``prestrain`` and ``base_slip`` (default 0).
    fail_below_E
        Raise (a failed solve) when ``E`` is below this value (Pa), mimicking
        the FSI model's failures for soft material.
    fail_above_load
        Raise (a failed solve) when the load factor ``(V/V0) (E0/E)`` (the displacement
        relative to ``u0``) exceeds this value, mimicking the FSI model's inverted
        elements where a soft material is loaded hard (e.g. the base model of the
        concealed stiffening case at 2 and 3 x the nominal inflow).
    prestrain_solvable
        ``(lo, hi)``: raise (a failed solve) when ``prestrain`` lies outside, mimicking
        a candidate effect whose solves fail on one side or everywhere but at 0 (e.g.
        inverted elements).

    Returns
    -------
    dict
        ``{"current": (n, 2) array, "reference": (n, 2) array}`` in mm.
    """
    E = float(params["E"])
    nu = float(params["nu"])
    V = float(params.get("V", V0))
    if E <= 0:
        raise ValueError(f"E must be positive, got {E}")
    if not -1.0 < nu < 0.5:
        raise ValueError(f"nu must lie in (-1, 0.5), got {nu}")
    if E < fail_below_E:
        raise RuntimeError(f"analytic model: E = {E:g} Pa below the failure threshold")
    if (V / V0) * (E0 / E) > fail_above_load:
        raise RuntimeError(f"analytic model: load factor {(V / V0) * (E0 / E):g} above "
                           f"{fail_above_load:g} (an inverted element, as it were)")
    ref = reference_interface(n_nodes, width, height, centre)
    t = np.linspace(0.0, np.pi, n_nodes)
    load = (V / V0) * (E0 / E) * u0
    shear = np.column_stack([np.sin(t) ** 2, -0.25 * np.sin(2 * t)])
    comp = np.column_stack([np.zeros_like(t), -np.sin(t)])
    u = load * ((1 - nu**2) * shear + (1 + nu) * (1 - 2 * nu) * comp)
    pre = float(params.get("prestrain", 0.0))
    if prestrain_solvable is not None and not (
            prestrain_solvable[0] <= pre <= prestrain_solvable[1]):
        raise RuntimeError(f"analytic model: prestrain = {pre:g} outside the solvable range "
                           f"{list(prestrain_solvable)}")
    base = np.array([centre, 0.0])
    grown = base + (1.0 + pre) * (ref - base)
    slip = float(params.get("base_slip", 0.0)) * (V / V0) * (E0 / E)
    current = grown + u + np.array([slip, 0.0])
    return {"current": current, "reference": ref}

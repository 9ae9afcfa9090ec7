"""Validation problems of the 3D solver against analytic references.

The same :class:`~bayescalib.models.fsi.solver.MonolithicSolver` as the 3D flow cell
(:mod:`bayescalib.models.fsi.model`, ``geometry.dim: 3``) solves two classical
problems whose answers no one here derived:

Solid alone: cantilever
    A block ``[0, l] x [0, t] x [0, t]`` clamped at ``x = 0`` (``u = d = 0``), loaded by
    a body force ``-rho g e_y`` (a line load ``q = rho g t^2`` per length), St.
    Venant–Kirchhoff with ``nu = 0`` and a load small enough that the response is
    linear. Beam theory gives the tip deflection (Timoshenko & Gere; Euler–Bernoulli
    bending plus Timoshenko's shear term)

        w_EB = q l^4 / (8 E I),      I = t^4 / 12,
        w_T  = w_EB + q l^2 / (2 kappa G A),   G = E / (2 (1 + nu)),  A = t^2,

    with Cowper's shear coefficient ``kappa = 10 (1 + nu) / (12 + 11 nu)`` of a
    rectangle (5/6 at ``nu = 0``). For ``l / t = 10`` the shear term is
    ``0.8 (t / l)^2 = 0.8 %`` of ``w_EB``; the remaining difference between 3D
    elasticity and Timoshenko's beam is of order ``(t / l)^2`` as well (the clamp
    restrains the warping of the section; with ``nu = 0`` there is no Poisson
    contraction for the clamp to hold). The computed deflection is the mean of
    ``d_y`` over the tip face ``x = l``.

Fluid alone: developed flow in a rectangular duct
    The box ``[0, l] x [0, H] x [0, W]`` with no-slip walls, the exact developed
    profile of volume rate ``Q`` at the inflow (:mod:`bayescalib.models.fsi.duct`) and
    do-nothing at the outflow. The steady Navier–Stokes solution is the developed flow
    itself (its convective term vanishes), so the centreline velocity anywhere is
    ``u_c = (G / mu) duct_velocity(H/2, W/2)`` and the pressure falls linearly,
    ``p(x) = G (l - x)`` with ``G = Q mu / duct_flow_rate(H, W)`` (the flow rate–
    pressure drop relation, White, *Viscous Fluid Flow*, eq. 3-48). The computed
    values: ``u_x`` at the centre ``(l/2, H/2, W/2)``, and the pressure drop between
    ``x = l/4`` and ``x = 3 l/4`` on the centreline against ``G l / 2``.

The 2D model as a limit: the extruded patch
    The 3D flow cell with the 2D model's half-ellipse extruded across the whole width
    (``shape: ridge``) and symmetry side walls (``side_walls: slip``) at the rate
    ``Q = q W`` is the 2D plane-strain problem at the rate ``q`` per unit width: its
    solution does not depend on z and has ``d_z = 0``. Compared: the 3D displacement
    at the mid-plane ``z = W/2`` at the 2D model's interface vertices against the 2D
    model's (both discretization errors enter: the two meshes differ), its variation
    between ``z = W/4`` and ``W/2``, and the largest ``|d_z|`` on the interface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescalib.models.fsi.duct import duct_flow_rate, duct_velocity
from bayescalib.models.fsi.geometry import generate_mesh
from bayescalib.models.fsi.problem import FSIProblem
from bayescalib.models.fsi.solver import MonolithicSolver, SolverControls

__all__ = ["CantileverResult", "DuctResult", "PlaneLimitResult", "cantilever", "cantilever_reference",
           "duct_flow", "plane_limit"]


@dataclass
class CantileverResult:
    """Tip deflection of the 3D cantilever and its beam-theory references.

    Attributes
    ----------
    deflection
        Mean of ``-d_y`` over the tip face (length units of the problem).
    euler_bernoulli, timoshenko
        ``w_EB`` and ``w_T`` of the module docstring.
    ndof
        Unknowns of the solve.
    ok
        Whether the solve converged.
    """

    deflection: float
    euler_bernoulli: float
    timoshenko: float
    ndof: int
    ok: bool


@dataclass
class DuctResult:
    """Centreline velocity and pressure drop of the duct flow and their references.

    Attributes
    ----------
    centre_velocity, centre_velocity_exact
        ``u_x(l/2, H/2, W/2)`` computed and from the series (mm/s for mm, s, mg).
    pressure_drop, pressure_drop_exact
        ``p(l/4) - p(3 l/4)`` on the centreline computed, and ``G l / 2``.
    ndof
        Unknowns of the solve.
    ok
        Whether the solve converged.
    """

    centre_velocity: float
    centre_velocity_exact: float
    pressure_drop: float
    pressure_drop_exact: float
    ndof: int
    ok: bool


def cantilever_reference(length: float, thickness: float, E: float, nu: float,
                         q: float) -> tuple[float, float]:
    """Euler–Bernoulli and Timoshenko tip deflections of a square cantilever.

    Parameters
    ----------
    length, thickness : float
        Beam length ``l`` and side ``t`` of its square section.
    E, nu : float
        Young's modulus and Poisson ratio.
    q : float
        Line load per unit length (force / length).

    Returns
    -------
    (w_EB, w_T) : tuple of float
        Tip deflections in length units.
    """
    inertia = thickness**4 / 12.0
    area = thickness**2
    shear_modulus = E / (2.0 * (1.0 + nu))
    kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)
    w_eb = q * length**4 / (8.0 * E * inertia)
    return w_eb, w_eb + q * length**2 / (2.0 * kappa * shear_modulus * area)


def _box_mesh(length: float, height: float, width: float, maxh: float, names: dict[str, str],
              region: str):
    """Tetrahedral mesh of ``[0, length] x [0, height] x [0, width]`` with named faces
    (keys ``xmin``, ``xmax``; the other four faces are ``wall``)."""
    import ngsolve as ng
    from netgen.occ import Box, OCCGeometry, Pnt, X

    box = Box(Pnt(0, 0, 0), Pnt(length, height, width))
    box.faces.name = "wall"
    box.faces.Min(X).name = names["xmin"]
    box.faces.Max(X).name = names["xmax"]
    box.solids.name = region
    return ng.Mesh(generate_mesh(OCCGeometry(box), maxh=maxh))


def cantilever(*, length: float = 1.0, thickness: float = 0.1, maxh: float = 0.05,
               E: float = 1.0e5, g: float = 0.1, law: str = "svk") -> CantileverResult:
    """Solve the clamped block under its weight (``rho = 1``, ``nu = 0``).

    Parameters
    ----------
    length, thickness : float
        Beam length and side of the square section (consistent units).
    maxh : float
        Element size.
    E : float
        Young's modulus.
    g : float
        Body acceleration (downwards, ``-y``); the default gives a tip deflection of
        1.5e-4 of the length (linear regime).
    law : str
        ``"svk"`` or ``"neo_hooke"``.

    Returns
    -------
    CantileverResult
    """
    import ngsolve as ng

    ng.SetNumThreads(1)
    mesh = _box_mesh(length, thickness, thickness, maxh, {"xmin": "clamp", "xmax": "tip"},
                     "solid")
    pb = FSIProblem(mesh=mesh, fluid=None, solids={"solid": law}, velocity_dirichlet="clamp",
                    displacement_dirichlet="clamp", rho_solid=1.0, body_force=(0.0, -g, 0.0),
                    length_scale=maxh)
    solver = MonolithicSolver(pb)
    solver.set_materials({"solid": (E, 0.0)})
    solver.reset()
    out = solver.solve(SolverControls())
    d = solver.gfu.components[solver.i_d]
    tip = ng.ds(definedon=mesh.Boundaries("tip"))
    w = -ng.Integrate(d[1] * tip, mesh) / ng.Integrate(ng.CoefficientFunction(1.0) * tip, mesh)
    w_eb, w_t = cantilever_reference(length, thickness, E, 0.0, g * thickness**2)
    return CantileverResult(float(w), w_eb, w_t, solver.ndof, out.ok)


def duct_flow(*, length: float = 2.0, height: float = 1.0, width: float = 1.0,
              maxh: float = 0.25, rate: float = 1.0, viscosity: float = 1.0,
              density: float = 1.0) -> DuctResult:
    """Solve the developed flow in a rectangular duct (fluid alone).

    Parameters
    ----------
    length, height, width : float
        Duct size, mm.
    maxh : float
        Element size, mm.
    rate : float
        Volume rate, mm^3/s.
    viscosity, density : float
        mg/(mm s) and mg/mm^3 (water: 1 and 1).

    Returns
    -------
    DuctResult
    """
    import ngsolve as ng

    ng.SetNumThreads(1)
    mesh = _box_mesh(length, height, width, maxh, {"xmin": "inlet", "xmax": "outlet"}, "fluid")
    unit = duct_flow_rate(height, width)

    def profile():
        return ng.CoefficientFunction(
            (rate / unit * duct_velocity(ng.y, ng.z, height, width, lib=ng), 0.0, 0.0))

    pb = FSIProblem(mesh=mesh, fluid="fluid", solids={}, velocity_dirichlet="inlet|wall",
                    displacement_dirichlet="inlet|outlet|wall", inflow="inlet",
                    inflow_profile=profile, rho_fluid=density, mu_fluid=viscosity,
                    length_scale=maxh)
    solver = MonolithicSolver(pb)
    solver.reset()
    out = solver.solve(SolverControls())
    u = solver.gfu.components[0]
    p = solver.gfu.components[solver.i_p]
    yc, zc = 0.5 * height, 0.5 * width
    G = rate * viscosity / unit
    u_exact = G / viscosity * float(duct_velocity(np.array(yc), np.array(zc), height, width))
    drop = p(mesh(0.25 * length, yc, zc)) - p(mesh(0.75 * length, yc, zc))
    return DuctResult(float(u(mesh(0.5 * length, yc, zc))[0]), u_exact, float(drop),
                      0.5 * G * length, solver.ndof, out.ok)


@dataclass
class PlaneLimitResult:
    """The 3D ridge with symmetry side walls against the 2D model (mm).

    Attributes
    ----------
    max_displacement_2d
        Largest interface displacement of the 2D model.
    max_difference
        Largest ``|d_3D(x, y, W/2) - d_2D(x, y)|`` over the 2D interface vertices
        (x, y components).
    max_out_of_plane
        Largest ``|d_z|`` of the 3D interface vertices (zero in the limit).
    max_z_variation
        Largest ``|d_3D(x, y, W/4) - d_3D(x, y, W/2)|`` over the 2D interface vertices.
    ndof_3d, ndof_2d
        Unknowns of the two solves.
    ok
        Whether both solves converged.
    """

    max_displacement_2d: float
    max_difference: float
    max_out_of_plane: float
    max_z_variation: float
    ndof_3d: int
    ndof_2d: int
    ok: bool


def plane_limit(mesh3d: dict, mesh2d: dict, *, rate: float = 100.0,
                width: float = 1.0) -> PlaneLimitResult:
    """Solve the 2D model and its extrusion (``shape: ridge``, slip side walls).

    Parameters
    ----------
    mesh3d, mesh2d : dict
        ``mesh`` sections of the 3D and the 2D model.
    rate : float
        The 2D model's inflow rate, mm^2/s; the 3D model gets ``rate * width`` mm^3/s.
    width : float
        Channel width, mm.

    Returns
    -------
    PlaneLimitResult
    """
    from bayescalib.models.fsi.model import FSIModel

    m2 = FSIModel({"mesh": mesh2d, "inflow": {"rate": rate}})
    r2 = m2.solve()
    m3 = FSIModel({"geometry": {"dim": 3, "shape": "ridge", "side_walls": "slip",
                                "channel_width": width},
                   "mesh": mesh3d, "inflow": {"rate": rate * width}})
    r3 = m3.solve()
    solver = m3.solver
    assert solver is not None
    d3 = solver.gfu.components[solver.i_d]
    mesh = solver.mesh
    ref2 = r2.interface_reference
    disp2 = r2.interface_current - ref2

    def at(z: float) -> np.ndarray:
        return np.array([d3(mesh(float(x), float(y), z)) for x, y in ref2], dtype=float)

    mid, quarter = at(0.5 * width), at(0.25 * width)
    disp3 = r3.interface_current - r3.interface_reference
    return PlaneLimitResult(
        max_displacement_2d=float(np.max(np.linalg.norm(disp2, axis=1))),
        max_difference=float(np.max(np.linalg.norm(mid[:, :2] - disp2, axis=1))),
        max_out_of_plane=float(np.max(np.abs(disp3[:, 2]))),
        max_z_variation=float(np.max(np.linalg.norm(quarter - mid, axis=1))),
        ndof_3d=int(r3.stats["ndof"]), ndof_2d=int(r2.stats["ndof"]), ok=r2.ok and r3.ok)

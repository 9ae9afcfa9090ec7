"""Turek–Hron benchmark problems (FSI1, CSM1, CFD1) on the same solver core.

Reference: S. Turek, J. Hron, "Proposal for numerical benchmarking of fluid-structure
interaction between an elastic object and laminar incompressible flow", in
*Fluid-Structure Interaction*, LNCSE 53, Springer 2006, pp. 371–385. SI units.

Geometry: channel ``[0, 2.5] x [0, 0.41]`` m, cylinder of radius 0.05 centred at
(0.2, 0.2), elastic flag ``0.35 x 0.02`` attached to the cylinder's downstream side,
tip point A = (0.6, 0.2). Inflow ``U(y) = 1.5 Ubar y (H - y) / (H/2)^2``; no-slip on the
walls and the cylinder; do-nothing outflow. Fluid: rho = 1000, nu = 1e-3 (mu = 1).
Solid: rho = 1000, mu_s = 0.5e6, nu_s = 0.4 (St. Venant–Kirchhoff).

* FSI1: Ubar = 0.2 (steady); ux(A) = 2.2695e-5, uy(A) = 8.2209e-4, drag 14.295, lift 0.7638.
* CSM1: the flag alone under gravity g = 2 m/s^2 (downwards);
  ux(A) = -7.187e-3, uy(A) = -6.610e-2.
* CFD1: rigid cylinder and flag, Ubar = 0.2; drag 14.29, lift 1.119.

The same :class:`~bayescalib.models.fsi.solver.MonolithicSolver` as for the biofilm is used:
CSM1 is the problem without the fluid region (body force option), CFD1 the problem
without the solid regions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bayescalib.models.fsi.problem import FSIProblem
from bayescalib.models.fsi.solver import MonolithicSolver, SolveOutcome, SolverControls

#: Reference values (Turek & Hron 2006), SI units
REFERENCE = {
    "FSI1": {"ux": 2.2695e-5, "uy": 8.2209e-4, "drag": 14.295, "lift": 0.7638},
    "CSM1": {"ux": -7.187e-3, "uy": -6.610e-2},
    "CFD1": {"drag": 14.29, "lift": 1.119},
}
POINT_A = (0.6, 0.2)
H = 0.41
L = 2.5


def _mesh(kind: str, h_flag: float, h_cyl: float, h_bulk: float, curve_order: int = 2):
    import ngsolve as ng
    from netgen.occ import Glue, OCCGeometry, WorkPlane, X

    cyl = WorkPlane().Circle(0.2, 0.2, 0.05).Face()
    cyl.edges.name = "cyl"
    flag = WorkPlane().MoveTo(0.2, 0.19).Rectangle(0.4, 0.02).Face()
    flag.edges.name = "interface"
    flag = flag - cyl
    flag.faces.name = "solid"
    flag.faces.maxh = h_flag
    for e in flag.edges:
        e.maxh = h_flag
    if kind == "CSM1":
        shape = flag
    else:
        channel = WorkPlane().Rectangle(L, H).Face()
        channel.edges.name = "wall"
        channel.edges.Min(X).name = "inlet"
        channel.edges.Max(X).name = "outlet"
        fluid = channel - cyl - flag
        fluid.faces.name = "fluid"
        for e in fluid.edges:
            if e.name == "cyl":
                e.maxh = h_cyl
        shape = Glue([fluid, flag]) if kind == "FSI1" else fluid
    from bayescalib.models.fsi.geometry import generate_mesh

    mesh = ng.Mesh(generate_mesh(OCCGeometry(shape, dim=2), maxh=h_bulk, grading=0.3))
    mesh.Curve(curve_order)
    return mesh


def problem(kind: str, h_flag: float = 0.01, h_cyl: float = 0.01, h_bulk: float = 0.06,
            order: int = 2, viscous_form: str = "gradient") -> FSIProblem:
    """The :class:`FSIProblem` of benchmark ``kind`` (``"FSI1"``, ``"CSM1"``, ``"CFD1"``).

    ``h_flag``, ``h_cyl``, ``h_bulk`` are the element sizes (m) on the flag, on the
    cylinder and elsewhere; ``viscous_form`` as in :class:`FSIProblem` (the biofilm model
    uses the default ``"gradient"``).
    """
    import ngsolve as ng

    if kind not in REFERENCE:
        raise ValueError(f"unknown Turek–Hron case '{kind}'; expected one of {sorted(REFERENCE)}")
    mesh = _mesh(kind, h_flag, h_cyl, h_bulk)
    ubar = 0.2

    def profile():
        return ng.CoefficientFunction((1.5 * ubar * ng.y * (H - ng.y) / (H / 2) ** 2, 0.0))

    if kind == "CSM1":
        return FSIProblem(
            mesh=mesh, fluid=None, solids={"solid": "svk"},
            velocity_dirichlet="cyl", displacement_dirichlet="cyl",
            rho_solid=1000.0, body_force=(0.0, -2.0), interface="interface",
            length_scale=h_flag, order=order,
        )
    return FSIProblem(
        mesh=mesh, fluid="fluid", solids={"solid": "svk"} if kind == "FSI1" else {},
        velocity_dirichlet="inlet|wall|cyl" + ("" if kind == "FSI1" else "|interface"),
        displacement_dirichlet="inlet|wall|outlet|cyl",
        inflow="inlet", inflow_profile=profile, rho_fluid=1000.0, mu_fluid=1.0,
        interface="interface", length_scale=h_flag, order=order, viscous_form=viscous_form,
    )


@dataclass
class BenchmarkResult:
    """Quantities of interest of a Turek–Hron run (SI units)."""

    outcome: SolveOutcome
    ux: float
    uy: float
    drag: float
    lift: float
    ndof: int
    max_interface_velocity: float


def run(kind: str, controls: SolverControls | None = None, **mesh_kw: Any) -> BenchmarkResult:
    """Solve benchmark ``kind`` and evaluate displacement of A, drag and lift."""
    import ngsolve as ng
    import numpy as np

    ng.SetNumThreads(1)
    pb = problem(kind, **mesh_kw)
    solver = MonolithicSolver(pb)
    if kind == "FSI1" or kind == "CSM1":
        E, nu = 2 * 0.5e6 * (1 + 0.4), 0.4
        solver.set_materials({"solid": (E, nu)})
    solver.reset()
    c = controls or SolverControls(initial_step=1.0 if kind != "CSM1" else 0.25)
    out = solver.solve(c)
    ux = uy = drag = lift = float("nan")
    if solver.i_d is not None:
        d = solver.gfu.components[solver.i_d]
        ux, uy = (float(v) for v in d(pb.mesh(*POINT_A)))
    if solver.has_fluid:
        body = "cyl|interface"
        drag, lift = solver.fluid_force(body)
    vmax = 0.0
    if pb.fluid is not None and solver.has_solid:
        ub = solver.gfu.components[0]
        pts = [v.point for el in pb.mesh.Elements(ng.BND) if el.mat == "interface"
               for v in (pb.mesh.vertices[w.nr] for w in el.vertices)]
        vmax = float(max(np.hypot(*ub(pb.mesh(*p))) for p in pts))
    return BenchmarkResult(out, ux, uy, drag, lift, solver.ndof, vmax)

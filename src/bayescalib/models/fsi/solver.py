"""Monolithic steady ALE fluid–structure solver core (paper App. B).

Formulation
-----------
The forms below are written for any space dimension: the same code solves a 2D problem
(triangles; the solid in plane strain, :func:`bayescalib.models.fsi.materials.piola1`)
and a 3D one (tetrahedra; ``I`` is then the 3 x 3 identity and ``F`` a 3 x 3 tensor),
the dimension being that of the mesh. All fields live on the reference (undeformed) mesh. Unknowns: velocity ``u`` (P2, one
space over fluid *and* solid), pressure ``p`` (P1, fluid only: Taylor–Hood) and
displacement ``d`` (P2, over both; in the fluid it is the ALE mesh displacement). With
``F = I + grad d``, ``J = det F`` the steady weak form is

* fluid momentum and mass (ALE, mesh velocity zero in the steady state, App. B.1), with
  by default the gradient (Laplacian) form of the viscous term, whose natural outflow
  condition is "do nothing" (``FSIProblem.viscous_form = "symmetric"`` uses
  ``G + G^T`` with ``G = grad u F^-1`` instead, natural condition: zero traction)::

      int_f  rho J (G u) . v + mu J G : (grad v F^-1)
             - p J tr(grad v F^-1) - q J tr(G)  dX,     G = grad u F^-1

* solid momentum (App. B.2), tested with the *same* velocity test function ``v``::

      int_s  P(F) : grad v - rho_s g . v  dX

  Because ``v`` is continuous across the interface, the traction balance of App. B.3 is
  satisfied weakly without an explicit coupling term.
* kinematics: the steady solid does not move, ``u = 0`` in the solid (tested with the
  displacement test function ``w``), which gives the no-slip condition ``u = d_t = 0``
  on the interface (App. B.3);
* ALE mesh: harmonic extension of the solid displacement into the fluid,
  ``alpha int_f grad d : grad w dX``, with a tiny weight ``alpha`` (it shares the
  interface rows with the ``u = 0`` form; a large weight lets the interface slip).
* permeable solid (candidate physics ``permeability``, derivation in
  :mod:`bayescalib.models.fsi.physics`): a fourth block, the pore pressure ``pi`` (P1 on
  the solid regions), appended after the displacement. In the solid, ``u`` is then the
  Darcy velocity: ``int_s u . w + (k/mu) (F^-T grad pi) . w dX`` on the rows of
  ``u = 0``; ``pi`` solves ``int_s J (F^-T grad pi) . (F^-T grad r) dX = 0`` with
  ``pi = p`` on the interface (penalty); the solid momentum gets the pore pressure
  ``- c pi J tr(grad v F^-1)``. At ``k = 0`` (``c = 0``) the blocks of the base model
  do not see ``pi``: their solution is the base solution to round-off.

Nonlinear solution
------------------
Newton's method with NGSolve's automatic linearization and UMFPACK, inside a load
continuation in the load factor ``lambda`` (scales the inflow and the body force):
start with ``initial_step``, halve the step on failure, grow it by ``growth`` on
success, give up below ``min_step``; a step never goes past a load already known to
fail unless the continuation has halved its distance to it since
(:func:`_short_of_known_failure`). A continuation that starts at rest (the zero
state) also scales the loads of the problem's candidate physics that act without flow
(a growth prestrain, a body force: ``physics.set_load_factor``), as rest is the
solution at zero load only with them at zero; one that starts from a converged state
at another load keeps them at full value. Convergence needs *both* the velocity increment
(relative to the velocity) and the displacement increment (absolute + relative) to be
small — a test on the whole vector would be dominated by the pressure. Optionally the
factorization is reused across iterations (chord steps) while the iteration contracts
fast enough; this saves most of the cost, which is the sparse LU factorization.

Every failure — Newton not converging, NaN, an inverted element (``det F <= 0`` at a
quadrature point of the solid or the fluid mesh), the wall-clock deadline — ends as a
:class:`SolveOutcome` with ``ok = False`` and a reason; the last converged state is kept.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from bayescalib.models.fsi.materials import piola1
from bayescalib.models.fsi.physics import PORE_PENALTY
from bayescalib.models.fsi.problem import FSIProblem


@dataclass
class SolverControls:
    """Newton and continuation settings.

    Attributes
    ----------
    rtol_velocity, atol_velocity
        Velocity increment test: ``max|du| <= atol_velocity + rtol_velocity * max|u|``.
    atol_displacement, rtol_displacement
        Displacement test: ``max|dd| <= atol_displacement + rtol_displacement * max|d|``
        (length units of the problem).
    max_iterations
        Newton iterations per load step before the step counts as failed.
    initial_step, min_step, growth
        Load continuation: first increment of the load factor, smallest allowed
        increment, growth factor after a converged step.
    time_limit
        Wall-clock limit in seconds for the whole solve (``None``: none).
    reuse_factorization
        Reuse the LU factorization (chord step) while the increments contract by at least
        ``reuse_contraction`` per iteration.
    reuse_contraction
        Contraction ratio below which the factorization is kept.
    chord_threshold
        Chord steps only once the scaled increment (relative to the solution) is below
        this value, i.e. in the asymptotic phase of Newton's method.
    """

    rtol_velocity: float = 1e-6
    atol_velocity: float = 1e-10
    atol_displacement: float = 1e-9
    rtol_displacement: float = 1e-5
    max_iterations: int = 20
    initial_step: float = 1.0
    min_step: float = 1.0 / 64
    growth: float = 2.0
    time_limit: float | None = None
    reuse_factorization: bool = True
    reuse_contraction: float = 0.3
    chord_threshold: float = 0.1

    @classmethod
    def from_config(cls, solver: Mapping[str, Any], *,
                    time_limit: float | None = None) -> SolverControls:
        """The controls of a validated ``fsi.solver`` section (its ``time_limit_s``
        unless ``time_limit`` is given); the other keys of the section are the
        model's, not the Newton loop's."""
        names = {f.name for f in fields(cls)} - {"time_limit"}
        limit = solver["time_limit_s"] if time_limit is None else time_limit
        return cls(**{k: solver[k] for k in names}, time_limit=float(limit))


@dataclass
class SolveOutcome:
    """Result of :meth:`MonolithicSolver.solve` (state stays in the solver)."""

    ok: bool
    reason: str
    load_fraction: float
    newton_iterations: int
    load_steps: int
    factorizations: int
    wall_time: float
    timings: dict[str, float] = field(default_factory=dict)


def _vector_space(mesh, order: int, dirichlet: str, dirichlet_xy: tuple[str, ...] | None):
    """P``order`` vector H1 space, Dirichlet on ``dirichlet`` or per component
    (``dirichlet_xy``: one regex per space dimension)."""
    import ngsolve as ng

    if dirichlet_xy is None:
        return ng.VectorH1(mesh, order=order, dirichlet=dirichlet)
    if len(dirichlet_xy) != mesh.dim:
        raise ValueError(f"component-wise Dirichlet boundaries: {len(dirichlet_xy)} given "
                         f"for a {mesh.dim}D mesh")
    names = ("dirichletx", "dirichlety", "dirichletz")
    return ng.VectorH1(mesh, order=order, **dict(zip(names, dirichlet_xy)))


def _compiled(cf, mode: str):
    """``cf.Compile()`` (NGSolve's expression-tree optimisation) unless ``mode == "none"``."""
    if mode == "none":
        return cf
    return cf.Compile(realcompile=(mode == "real"), wait=True)


class _Failure(Exception):
    """Internal: a load step failed (reason in ``args[0]``); ``fatal`` stops the solve."""

    def __init__(self, reason: str, fatal: bool = False):
        super().__init__(reason)
        self.fatal = fatal


class MonolithicSolver:
    """Steady monolithic ALE FSI solver for one :class:`FSIProblem`.

    Material values are NGSolve ``Parameter`` objects, so new E, nu per solve reuse the
    compiled forms. The state (all unknowns) is held in :attr:`gfu`.

    Parameters
    ----------
    problem
        The problem description (mesh, regions, boundary data, constants).
    """

    def __init__(self, problem: FSIProblem):
        import ngsolve as ng

        self.problem = pb = problem
        mesh = pb.mesh
        self.mesh = mesh
        #: space dimension (2 or 3); 3D meshes must be tetrahedral
        self.dim = int(mesh.dim)
        order = pb.order
        self.has_fluid = pb.fluid is not None
        self.has_solid = bool(pb.solids)

        spaces = []
        V = _vector_space(mesh, order, pb.velocity_dirichlet, pb.velocity_dirichlet_xy)
        spaces.append(V)
        self.Vspace = V
        if self.has_fluid:
            Q = ng.H1(mesh, order=order - 1, definedon=pb.fluid)
            spaces.append(Q)
        if self.has_solid:
            D = _vector_space(mesh, order, pb.displacement_dirichlet, pb.displacement_dirichlet_xy)
            spaces.append(D)
        self.i_u = 0
        self.i_p = 1 if self.has_fluid else None
        self.i_d = (len(spaces) - 1) if self.has_solid else None
        # pore pressure of a permeable biofilm (candidate physics), last block
        self.permeable = bool(getattr(pb.physics, "permeable", False))
        self.i_pore = None
        if self.permeable:
            if not (self.has_fluid and self.has_solid and pb.interface is not None):
                raise ValueError("a permeable solid needs a fluid, solid regions and an interface")
            spaces.append(ng.H1(mesh, order=order - 1, definedon="|".join(pb.solids)))
            self.i_pore = len(spaces) - 1
        X = ng.FESpace(spaces)
        self.X = X
        self.gfu = ng.GridFunction(X)
        self._inv = None
        self.ncomp = len(spaces)

        self.load = ng.Parameter(0.0)
        self.E = {name: ng.Parameter(1.0) for name in pb.solids}
        self.nu = {name: ng.Parameter(0.0) for name in pb.solids}

        self.a, self._fluid_form = self._build_forms()

        # Dirichlet data of the inflow at full load, restricted to its DOFs.
        x = self.gfu.vec.FV().NumPy()
        self._inflow_idx = np.zeros(0, dtype=int)
        self._inflow_val = np.zeros(0)
        self._inflow_local = np.zeros(0, dtype=int)
        if pb.inflow is not None:
            mask = np.array(list(V.GetDofs(mesh.Boundaries(pb.inflow))), dtype=bool)
            mask &= ~np.array(list(V.FreeDofs()), dtype=bool)
            self._inflow_local = np.nonzero(mask)[0]
            # VectorH1 DOFs: component blocks of size V.ndof // dim
            self._inflow_idx = self._inflow_local + X.Range(0).start
            self._inflow_val = self.inflow_values(pb.inflow_profile())
        self._x = x
        self._freedofs = X.FreeDofs()
        for i in self._contact_line_dofs():
            self._freedofs.Set(X.Range(0).start + i)
        for i in self._unseen_pressure_dofs():
            self._freedofs.Clear(X.Range(self.i_p).start + i)
        self._free = np.array(list(self._freedofs), dtype=bool)
        self._ranges = [(X.Range(i).start, X.Range(i).stop) for i in range(self.ncomp)]
        self._res = self.gfu.vec.CreateVector()
        self._du = self.gfu.vec.CreateVector()
        self._ir_points = None
        self._from_rest = False
        if self.has_solid:
            self._detF = ng.Det(ng.Id(self.dim) + ng.Grad(self.gfu.components[self.i_d]))
            ir = ng.IntegrationRule(ng.TRIG if self.dim == 2 else ng.TET, 2 * order)
            self._ir_points = mesh.MapToAllElements(ir, ng.VOL)

    def _contact_line_dofs(self) -> list[int]:
        """Tangential velocity DOFs (of the velocity space) to keep free where the base slides.

        Where the spring boundary (a sliding base on the floor, normal y) meets a
        boundary whose tangential velocity (x; in 3D x and z) is Dirichlet (the fluid's
        no-slip floor), the shared nodes would be Dirichlet in that component. Its rows
        are the ones that carry the solid's tangential momentum (the solid's momentum is
        tested with the velocity test function, so that the fluid's traction and the
        solid's stress meet in the same rows): a Dirichlet velocity there drops the
        force balance of the base's edge, and its tangential displacement is then set
        by the ALE extension instead of by the solid and the springs (measured in 2D:
        the foot moved 12 um at compliance 1e-4 mm/Pa and inverted the solid's foot
        element at 1e-5 and below). Kept free, the velocity there is still 0: the
        solid's ``u = 0`` rows hold it. In 2D the contact line is the base's two end
        points (vertex DOFs); in 3D it is the base's rim, a curve: its vertex and edge
        DOFs (P2), in x and in z. Nodes on a boundary where the same component of the
        displacement is Dirichlet (a symmetry wall in z that the base of a ridge
        touches) keep their Dirichlet velocity: the solid's ``u = 0`` row of that
        component is not there to hold it. A component block of the vector space is
        numbered as the scalar space of the same order.
        """
        pb = self.problem
        if pb.spring_boundary is None or pb.velocity_dirichlet_xy is None:
            return []
        import re

        import ngsolve as ng

        spring = re.compile(pb.spring_boundary)
        scalar = ng.H1(self.mesh, order=pb.order)
        nd = self.Vspace.ndof // self.dim
        d_xy = pb.displacement_dirichlet_xy or (pb.displacement_dirichlet,) * self.dim
        out: list[int] = []
        for c in (k for k in range(self.dim) if k != 1):
            dirichlet_u, dirichlet_d = re.compile(pb.velocity_dirichlet_xy[c]), re.compile(d_xy[c])
            on_spring, on_dirichlet, held = set(), set(), set()
            for el in self.mesh.Elements(ng.BND):
                nodes = {ng.NodeId(ng.VERTEX, v.nr) for v in el.vertices}
                if self.dim == 3:
                    nodes |= {ng.NodeId(ng.EDGE, e.nr) for e in el.edges}
                if spring.fullmatch(el.mat):
                    on_spring |= nodes
                else:
                    if dirichlet_u.fullmatch(el.mat):
                        on_dirichlet |= nodes
                    if dirichlet_d.fullmatch(el.mat):
                        held |= nodes
            for node in (on_spring & on_dirichlet) - held:
                out.extend(c * nd + i for i in scalar.GetDofNrs(node))
        return sorted(out)

    def _unseen_pressure_dofs(self) -> list[int]:
        """Pressure DOFs that no free velocity DOF sees (3D only), to be held at zero.

        The pressure enters the equations only through ``int p div v`` over the fluid
        elements that hold its DOF. In 3D, Netgen may put a tetrahedron into a corner of
        the channel where three Dirichlet walls meet (the inflow and two no-slip walls):
        its four vertices and six edges all lie on them, so every P2 velocity DOF of it
        is prescribed, and a corner vertex that belongs to this element only carries a
        P1 pressure DOF with no equation of its own (a zero row and column: UMFPACK
        reports a singular matrix). Such DOFs are taken out of the unknowns (value 0);
        no other unknown depends on them, so the solution is unchanged elsewhere. A 2D
        mesh has no such element (a corner triangle's third edge is interior): nothing
        is done there.
        """
        if not self.has_fluid or self.dim != 3:
            return []
        import ngsolve as ng

        free_v = self.Vspace.FreeDofs()
        Q = self.X.components[self.i_p]
        fluid = self.mesh.Materials(self.problem.fluid).Mask()
        seen: set[int] = set()
        held: set[int] = set()
        for el in self.mesh.Elements(ng.VOL):
            if not fluid[el.index]:
                continue
            qd = [d for d in Q.GetDofNrs(el) if d >= 0]
            held.update(qd)
            if any(free_v[d] for d in self.Vspace.GetDofNrs(el) if d >= 0):
                seen.update(qd)
        return sorted(held - seen)

    def inflow_values(self, profile) -> np.ndarray:
        """Values of the velocity profile ``profile`` (vector coefficient function) at the
        inflow Dirichlet DOFs, in the order of the solver's inflow data."""
        import ngsolve as ng

        tmp = ng.GridFunction(self.Vspace)
        tmp.Set(profile, ng.BND, definedon=self.mesh.Boundaries(self.problem.inflow))
        return tmp.vec.FV().NumPy()[self._inflow_local].copy()

    def inflow_rate(self, values: np.ndarray | None = None) -> float:
        """Volume rate through the inflow boundary, ``- int u . n ds`` (2D: per unit
        depth), of the velocity with ``values`` at the inflow Dirichlet DOFs (the
        order of :meth:`inflow_values`) and zero elsewhere; ``None``: the current
        state's velocity."""
        import ngsolve as ng

        gf = ng.GridFunction(self.Vspace)
        if values is None:
            s, e = self._ranges[self.i_u]
            gf.vec.FV().NumPy()[:] = self._x[s:e]
        else:
            gf.vec.FV().NumPy()[self._inflow_local] = values
        n = ng.specialcf.normal(self.dim)
        return -float(ng.Integrate(ng.InnerProduct(gf, n), self.mesh, ng.BND,
                                   definedon=self.mesh.Boundaries(self.problem.inflow),
                                   order=2 * self.problem.order))

    def _build_forms(self):
        """The full nonlinear form and the fluid-momentum-only form used for forces."""
        import ngsolve as ng

        pb = self.problem
        mesh = self.mesh
        X = self.X
        trials, tests = X.TnT()
        u, v = trials[0], tests[0]
        if self.has_solid:
            d, w = trials[self.i_d], tests[self.i_d]
            F = F_fluid = ng.Id(self.dim) + ng.Grad(d)
        else:
            d = w = None
            F = F_fluid = ng.Id(self.dim)
        a = ng.BilinearForm(X, symmetric=False)
        fluid_form = None
        if self.has_fluid:
            p, q = trials[self.i_p], tests[self.i_p]
            J = ng.Det(F_fluid)
            Finv = ng.Inv(F_fluid)
            gu = ng.Grad(u) * Finv
            gv = ng.Grad(v) * Finv
            dxf = ng.dx(definedon=mesh.Materials(pb.fluid))
            visc_u = gu if pb.viscous_form == "gradient" else gu + gu.trans
            momentum = (
                pb.rho_fluid * J * ng.InnerProduct(gu * u, v)
                + pb.mu_fluid * J * ng.InnerProduct(visc_u, gv)
                - J * ng.Trace(gv) * p
            )
            a += _compiled(momentum - J * ng.Trace(gu) * q, pb.compile) * dxf
            fluid_form = ng.BilinearForm(X, symmetric=False)
            fluid_form += momentum * dxf
            if self.has_solid:
                alpha = pb.ale_weight * pb.length_scale**2
                a += alpha * ng.InnerProduct(ng.Grad(d), ng.Grad(w)) * dxf
        if self.has_solid:
            g = ng.CoefficientFunction(tuple(float(c) for c in pb.body_force))
            ph = pb.physics
            for name, law in pb.solids.items():
                dxs = ng.dx(definedon=mesh.Materials(name))
                P = piola1(law, F, self.E[name], self.nu[name],
                           growth=None if ph is None else ph.growth(),
                           stiffening=None if ph is None else ph.stiffening())
                factor = None if ph is None else ph.stress_factor()
                if factor is not None:
                    P = factor * P
                a += _compiled(ng.InnerProduct(P, ng.Grad(v)), pb.compile) * dxs
                if any(pb.body_force):
                    a += -self.load * pb.rho_solid * ng.InnerProduct(g, v) * dxs
                bf = None if ph is None else ph.body_force()
                if bf is not None:
                    a += -ng.InnerProduct(bf, v) * dxs
                a += ng.InnerProduct(u, w) * dxs
                if self.permeable:
                    a += self._pore_forms(F, v, w, trials[self.i_pore], tests[self.i_pore], dxs)
            if self.permeable:
                # pore pressure = fluid pressure on the interface (penalty, reference length)
                pi, r = trials[self.i_pore], tests[self.i_pore]
                p = trials[self.i_p]
                beta = PORE_PENALTY / pb.length_scale
                a += beta * (pi - p) * r * ng.ds(definedon=mesh.Boundaries(pb.interface))
            if pb.spring_boundary is not None:
                # tangential springs on a floor (normal y): x, and in 3D z
                dsb = ng.ds(definedon=mesh.Boundaries(pb.spring_boundary))
                for c in (k for k in range(self.dim) if k != 1):
                    a += pb.physics.spring_stiffness * d[c] * v[c] * dsb
        return a, fluid_form

    def _pore_forms(self, F, v, w, pi, r, dxs):
        """Poroelastic terms of one solid region (candidate ``permeability``, see
        :mod:`bayescalib.models.fsi.physics`): Darcy's law on the ``u = 0`` rows, the
        k-free pore-pressure equation, and the pore pressure in the total stress."""
        import ngsolve as ng

        ph = self.problem.physics
        J = ng.Det(F)
        Finv = ng.Inv(F)
        grad_pi = Finv.trans * ng.Grad(pi)
        compile_mode = self.problem.compile
        form = ph.darcy_mobility * ng.InnerProduct(grad_pi, w) * dxs
        form += _compiled(J * ng.InnerProduct(grad_pi, Finv.trans * ng.Grad(r)), compile_mode) * dxs
        form += -ph.pore_coupling * _compiled(J * ng.Trace(ng.Grad(v) * Finv) * pi,
                                              compile_mode) * dxs
        return form

    # ------------------------------------------------------------------ state access
    @property
    def ndof(self) -> int:
        """Number of unknowns (all, including Dirichlet DOFs)."""
        return int(self.X.ndof)

    @property
    def nfree(self) -> int:
        """Number of free unknowns (the size of the linear systems)."""
        return int(self._free.sum())

    def get_state(self) -> np.ndarray:
        """Copy of the full state vector, shape (ndof,)."""
        return self._x.copy()

    def set_state(self, state: np.ndarray) -> None:
        """Set the full state vector (shape (ndof,))."""
        state = np.asarray(state, dtype=float)
        if state.shape != self._x.shape:
            raise ValueError(f"state has {state.shape[0]} entries, the solver has {self._x.shape[0]} unknowns")
        self._x[:] = state

    def reset(self) -> None:
        """Zero state (fluid at rest, undeformed)."""
        self._x[:] = 0.0

    @property
    def factorization(self) -> Any:
        """The LU factorization kept from the last Newton step for chord steps of a solve
        with ``keep_factorization`` (``None``: none kept)."""
        return self._inv

    @factorization.setter
    def factorization(self, inv: Any) -> None:
        self._inv = inv

    def set_materials(self, values: dict[str, tuple[float, float]]) -> None:
        """Set ``(E, nu)`` per solid region (solver stress units)."""
        for name, (E, nu) in values.items():
            self.E[name].Set(float(E))
            self.nu[name].Set(float(nu))

    def block(self, i: int) -> np.ndarray:
        """View of the state entries of component ``i`` (0 velocity, then pressure, displacement)."""
        s, e = self._ranges[i]
        return self._x[s:e]

    def min_det_F(self) -> float:
        """Minimum of ``det F`` over quadrature points of the whole mesh (1 if no solid)."""
        if self._ir_points is None:
            return 1.0
        vals = np.asarray(self._detF(self._ir_points))
        return float(np.min(vals)) if vals.size else 1.0

    def _apply_load(self, lam: float) -> None:
        self.load.Set(lam)
        if self._inflow_idx.size:
            self._x[self._inflow_idx] = lam * self._inflow_val
        physics = self.problem.physics
        if physics is not None:
            # the loads without flow: with the load factor on the way up from rest,
            # else at full value (a factor of exactly 1 leaves them bitwise as set)
            physics.set_load_factor(min(lam, 1.0) if self._from_rest else 1.0)

    def fluid_force(self, boundary: str) -> tuple[float, ...]:
        """Force of the fluid on ``boundary`` (regex), ``(Fx, Fy)`` (3D: ``(Fx, Fy, Fz)``),
        from the fluid residual.

        The residual of the fluid momentum form, tested with a function that is the unit
        vector on ``boundary`` and zero on all other boundaries, equals the boundary
        integral of the fluid traction (a volume-based, Babuška–Miller type evaluation,
        more accurate than a boundary integral of derivatives).
        """
        import ngsolve as ng

        if self._fluid_form is None:
            raise ValueError("problem has no fluid")
        res = self.gfu.vec.CreateVector()
        self._fluid_form.Apply(self.gfu.vec, res)
        r = res.FV().NumPy()
        out = []
        for comp in np.eye(self.dim):
            wv = ng.GridFunction(self.Vspace)
            wv.Set(ng.CoefficientFunction(tuple(float(c) for c in comp)), ng.BND, definedon=self.mesh.Boundaries(boundary))
            s, e = self._ranges[0]
            out.append(-float(np.dot(r[s:e], wv.vec.FV().NumPy())))
        return tuple(out)

    # ------------------------------------------------------------------ solving
    def _converged(self, du: np.ndarray) -> tuple[bool, float]:
        """Separate increment tests on velocity and displacement; returns (ok, scaled size)."""
        pb_ok = True
        scaled = 0.0
        s, e = self._ranges[self.i_u]
        dv = float(np.max(np.abs(du[s:e]))) if e > s else 0.0
        vmax = float(np.max(np.abs(self._x[s:e]))) if e > s else 0.0
        if self.has_fluid:
            tol_v = self.controls.atol_velocity + self.controls.rtol_velocity * vmax
            pb_ok &= dv <= tol_v
            scaled = max(scaled, dv / max(vmax, self.controls.atol_velocity * 1e3, 1e-300))
        if self.has_solid:
            s, e = self._ranges[self.i_d]
            dd = float(np.max(np.abs(du[s:e])))
            dmax = float(np.max(np.abs(self._x[s:e])))
            tol_d = self.controls.atol_displacement + self.controls.rtol_displacement * dmax
            pb_ok &= dd <= tol_d
            scaled = max(scaled, dd / max(dmax, self.controls.atol_displacement * 1e3, 1e-300))
        return pb_ok, scaled

    def _enforce_deadline(self, deadline: float | None) -> None:
        if deadline is not None and time.perf_counter() > deadline:
            raise _Failure("wall-clock time limit reached", fatal=True)

    def _newton(self, deadline: float | None, stats: dict) -> None:
        """Newton at the current load, raising :class:`_Failure` when it fails.

        With ``reuse_factorization`` a factorization (also one kept from an earlier load
        step or solve, :attr:`_inv`) is used for chord steps as long as each step
        contracts the increment by ``reuse_contraction``; a chord step that does not
        contract, produces NaN or inverts an element is undone and the Jacobian is
        re-factorized instead (such steps are never counted as a failure).
        """
        c = self.controls
        inv = self._inv if c.reuse_factorization else None
        prev = None
        iters_this_step = 0
        while True:
            if iters_this_step >= c.max_iterations:
                break
            self._enforce_deadline(deadline)
            t0 = time.perf_counter()
            self.a.Apply(self.gfu.vec, self._res)
            t1 = time.perf_counter()
            stats["t_residual"] += t1 - t0
            if inv is None:
                try:
                    self.a.AssembleLinearization(self.gfu.vec)
                    t2 = time.perf_counter()
                    stats["t_assemble"] += t2 - t1
                    self._enforce_deadline(deadline)
                    inv = self.a.mat.Inverse(self._freedofs, inverse="umfpack")
                except _Failure:
                    raise
                except Exception as exc:  # noqa: BLE001 - NGSolve/UMFPACK errors, e.g. a singular Jacobian
                    raise _Failure(f"linear solver failed: {exc} (iteration {iters_this_step + 1})") from None
                stats["t_factor"] += time.perf_counter() - t2
                stats["factorizations"] += 1
                fresh = True
            else:
                fresh = False
            t3 = time.perf_counter()
            self._du.data = inv * self._res
            stats["t_solve"] += time.perf_counter() - t3
            du = self._du.FV().NumPy()
            stats["iterations"] += 1
            iters_this_step += 1
            it = iters_this_step
            if not np.all(np.isfinite(du)):
                if not fresh:
                    inv = None
                    continue
                raise _Failure(f"NaN/Inf in the Newton increment (iteration {it})")
            ok, size = self._converged(du)
            if not fresh and prev is not None and size > prev:
                # chord step does not contract: discard it (not applied) and re-factorize
                self.history.append((float(self.load.Get()), it, size, fresh))
                inv = None
                continue
            self._x -= du
            if not np.all(np.isfinite(self._x)):
                raise _Failure(f"NaN/Inf in the solution (iteration {it})")
            self.history.append((float(self.load.Get()), it, size, fresh))
            jmin = self.min_det_F()
            if not (jmin > 0.0):
                if not fresh:
                    self._x += du
                    inv = None
                    continue
                raise _Failure(f"inverted element: min det F = {jmin:.3g} (iteration {it})")
            if ok:
                self._inv = inv if c.reuse_factorization else None
                return
            if prev is not None and size > 1e3 * max(prev, 1e-300) and fresh:
                raise _Failure(f"Newton diverging (iteration {it})")
            keep = (
                c.reuse_factorization
                and size <= c.chord_threshold
                and (prev is None or size <= c.reuse_contraction * prev)
            )
            if not keep:
                inv = None
            prev = size
        self._inv = None
        raise _Failure(f"Newton did not converge in {c.max_iterations} iterations")

    def solve(self, controls: SolverControls, *, initial: np.ndarray | None = None,
              start_load: float = 0.0, keep_factorization: bool = False) -> SolveOutcome:
        """Solve at full load by continuation in the load factor.

        Parameters
        ----------
        controls
            Newton and continuation settings.
        initial
            Initial state (e.g. a warm start); ``None`` keeps the current state.
        start_load
            Load factor at which ``initial`` is an (approximate) solution; the
            continuation starts from there (0 for rest, 1 for a warm start at full load,
            above 1 for a state at a higher load: the continuation then goes down).
        keep_factorization
            Start with the factorization kept from the previous solve (chord steps; it is
            replaced as soon as it stops contracting). Useful for a warm start at nearby
            parameters.

        Returns
        -------
        SolveOutcome
            The state (converged, or the last converged one on failure) is in :attr:`gfu`.
        """
        t_start = time.perf_counter()
        self.controls = controls
        deadline = None if controls.time_limit is None else t_start + controls.time_limit
        stats = {"t_residual": 0.0, "t_assemble": 0.0, "t_factor": 0.0, "t_solve": 0.0,
                 "iterations": 0, "factorizations": 0}
        if not keep_factorization:
            self._inv = None
        #: (load, iteration, scaled increment, fresh factorization) per Newton iteration
        self.history: list[tuple[float, int, float, bool]] = []
        #: messages of failed load steps (before step halving)
        self.failures: list[str] = []
        if initial is not None:
            self.set_state(initial)
        steps = 0
        reason = ""
        lam = float(max(start_load, 0.0))
        #: the continuation starts at rest: the loads without flow go up with lambda
        self._from_rest = lam == 0.0 and not np.any(self._x)
        if lam > 0.0:
            # converge at the starting load first; if the initial state is too far off,
            # fall back to the continuation from rest
            self._apply_load(lam)
            try:
                self._newton(deadline, stats)
                steps += 1
            except _Failure as fail:
                # the initial state is no solution of this problem: report rest on a
                # fatal failure, else restart the continuation from rest
                self.failures.append(f"start at load {lam:.4g}: {fail}")
                self._inv = None
                if fail.fatal:
                    reason = str(fail)
                lam = 0.0
                self._x[:] = 0.0
                self._from_rest = True
        self._apply_load(lam)
        saved = self._x.copy()
        step = float(controls.initial_step)
        #: nearest load known to fail ahead, and the load it was tried from
        failed_at: tuple[float, float] | None = None
        while lam != 1.0 and not reason:
            # towards the full load from below (from rest) or from above (a state at a
            # higher load, e.g. the previous snapshot of a series of loadings)
            new = min(1.0, lam + step) if lam < 1.0 else max(1.0, lam - step)
            new = _short_of_known_failure(lam, new, failed_at)
            try:
                self._apply_load(new)
                self._newton(deadline, stats)
            except _Failure as fail:
                self.history.append((new, -1, float("nan"), False))
                self.failures.append(f"load {new:.4g}: {fail}")
                self._x[:] = saved
                self._apply_load(lam)
                self._inv = None
                if fail.fatal:
                    reason = str(fail)
                    break
                failed_at = (new, lam)
                step = 0.5 * abs(new - lam)
                if step < controls.min_step:
                    reason = f"load continuation stalled: {fail} (step below {controls.min_step:g})"
                continue
            steps += 1
            if failed_at is not None and new == failed_at[0]:
                failed_at = None
            lam = new
            saved[:] = self._x
            step = min(step * controls.growth, 1.0)
        ok = lam == 1.0 and not reason
        wall = time.perf_counter() - t_start
        timings = {k: v for k, v in stats.items() if k.startswith("t_")}
        return SolveOutcome(
            ok=ok,
            reason="" if ok else (reason or "not converged"),
            load_fraction=float(lam),
            newton_iterations=int(stats["iterations"]),
            load_steps=steps,
            factorizations=int(stats["factorizations"]),
            wall_time=wall,
            timings=timings,
        )


def _short_of_known_failure(lam: float, new: float,
                            failed_at: tuple[float, float] | None) -> float:
    """The next load of the continuation, never past a load known to fail.

    ``failed_at = (load, tried_from)``: the nearest load ahead whose step failed, and
    the load that step started from. A step may end at that load again only once the
    continuation has come at least twice as close to it; before that it ends halfway
    (bisection towards the failure). Near a limit point or an element inversion the
    continuation thus closes in on the failing load with one failed step per halving
    of the distance, instead of re-trying loads beyond it after every success.
    """
    if failed_at is None:
        return new
    bad, start = failed_at
    ahead = (new - bad) * (bad - lam) >= 0.0        # new at or past the failing load
    if not ahead:
        return new
    if abs(bad - lam) <= 0.5 * abs(bad - start):
        return bad
    return 0.5 * (lam + bad)


__all__ = ["MonolithicSolver", "SolveOutcome", "SolverControls"]

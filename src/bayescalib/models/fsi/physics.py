"""Candidate physics for model-form diagnosis: nested extensions of the FSI model.

Each candidate adds one effect that the paper's base model (homogeneous SVK biofilm,
clamped base, parabolic inflow, no body force) leaves out. Each has a single extra
parameter ``phi`` (config key ``physics.<name>.phi``) and is *nested*: at ``phi = 0``
the extended weak form is the base form exactly (a factor ``exp(0) = 1``, a zero
term, or — for the attachment springs — the base clamp itself), so the base model is
recovered to solver round-off. The switch ``physics.<name>.enabled`` adds the terms to
the compiled forms; ``phi`` is an NGSolve ``Parameter``, so a new value recompiles
nothing. Units: config in mm, Pa, kg/m^3; the solver works in mm, s, mg (stresses in
mPa, see :mod:`bayescalib.models.fsi.model`).

Notation: ``F = I + grad d`` (2 x 2, plane strain, ``F_33 = 1``; 3 x 3 in the 3D model,
see "The 3D model" below), ``S`` the second
Piola–Kirchhoff stress of the law, ``P`` the first, ``W`` the stored energy per unit
reference volume, ``chi`` an indicator function, ``H`` the channel height.

1. ``layer`` — heterogeneous stiffness. A layer of thickness ``t`` at the base
   (``y < t``) or under the top of the patch (``y > h - t``, ``h`` the patch height)
   has Young's modulus ``E exp(phi)``: since both Lamé constants are linear in E,
   ``P = exp(phi chi_layer) P_base``. ``phi = ln(E_layer/E)``, dimensionless. The
   layer is an indicator on the reference mesh (no re-meshing, so that ``phi = 0``
   is the same discrete problem); its boundary cuts elements, an error of the order
   of the quadrature of a step function, not in the nestedness.
2. ``growth`` — isotropic growth or swelling prestrain, multiplicative split
   ``F = F_e F_g`` with ``F_g = g I_3``, ``g = 1 + phi``. In plane strain
   ``F_e = F / g`` in the plane and ``F_e,33 = 1/g``. The energy per reference volume is
   ``g^3 W(F_e)``, hence ``P = g^3 dW/dF_e : dF_e/dF = g^2 F_e S_e = g F S_e`` with
   ``S_e`` the in-plane block of the law's stress at ``C_e = F^T F / g^2``,
   ``C_e,33 = g^-2`` (SVK: ``S_e = lambda tr E_e I + 2 mu E_e`` with the 3D trace
   ``tr E_e = tr_2 E_e + (g^-2 - 1)/2``; neo-Hooke: ``S_e = mu (I - C_e^-1) +
   lambda ln J_e C_e^-1`` with ``J_e = det F / g^3``). A swelling patch (phi > 0)
   bulges up with no flow at all; the base stays clamped.
3. ``attachment`` — imperfect attachment. The base ``y = 0`` of the biofilm is not
   clamped but held by distributed tangential springs of compliance ``phi`` (mm/Pa):
   traction ``t_x = -d_x / phi`` on the base (in 3D also ``t_z = -d_z / phi``), with
   ``d_y = 0`` (no lift-off, no penetration). Weak form: ``+ int_base d_x v_x / phi ds``. The ALE mesh may slide
   along the flat fluid floor (``d_y = 0`` there), so the feet can move. ``phi = 0``
   is the clamp of the base model (the springs are switched in for ``phi > 0`` only;
   the change of boundary condition rebuilds the spaces once). Springs let the base
   slide downstream under the shear of the flow. The base's two end points, where it
   meets the no-slip floor, keep their x-velocity free
   (``MonolithicSolver._contact_line_dofs``): their force balance with the springs sets
   how far they slide, so the interface tends continuously to the clamp's as
   ``phi -> 0`` (1.5e-3 um away at 1e-8 mm/Pa).
4. ``inflow_skew`` — inflow disturbance. The inflow profile is skewed at the same
   volume rate ``V``: ``u_x(y) = 6 V y (H - y) / H^3 (1 + phi (2 y/H - 1))``; the
   added term is odd about ``y = H/2``, so it integrates to zero, and ``|phi| <= 1``
   keeps the profile non-negative. ``phi > 0`` shifts the flow towards the top,
   away from the biofilm, and lowers the load on it. In 3D the duct profile
   ``u_x(y, z)`` is multiplied by the same factor (the profile is even about
   ``y = H/2`` as the parabola is). On the mesh the discrete odd term is made free of
   volume: the model subtracts from it the multiple of the discrete profile that its
   discrete volume rate is (an inlet mesh not symmetric in y gives the plain product
   a rate of 1.3e-3 of the profile's on the 3D ``very_coarse`` mesh, 1e-17 in 2D),
   so that the skew keeps the volume rate to round-off.
5. ``stiffening`` — strain stiffening of Fung type. The stored energy
   ``W_f = mu/(2 phi) (exp(2 phi W / mu) - 1)`` tends to ``W`` as ``phi -> 0`` and
   gives ``P_f = exp(2 phi W / mu) P``; ``phi >= 0`` dimensionless (``W/mu`` is a
   strain measure squared, so stiffening becomes visible when ``phi`` times the squared
   strain is of order 0.1). Uses the energy of the chosen law (with growth, ``W`` of
   ``F_e``).
6. ``gravity`` — density mismatch between biofilm and water, ``phi = rho_b - rho_w``
   (kg/m^3): a body force ``-phi g e_y`` on the biofilm (``g = 9.81 m/s^2``; the
   model's pressure is the dynamic pressure, so the hydrostatic part and the
   buoyancy of the water's own density cancel). A physically small effect: a useful
   negative control for the diagnosis.

7. ``permeability`` — permeable (poroelastic) biofilm, ``phi = k`` the intrinsic
   permeability of the biofilm in um^2 (1 um^2 = 1e-12 m^2 = 1e-6 mm^2). The biofilm is
   a saturated porous skeleton; water flows through it by Darcy's law. Steady state:
   the skeleton is at rest, so the Darcy (filtration) velocity relative to it is the
   fluid flux itself, and the one velocity unknown ``u`` of the solver is, in the
   biofilm, this filtration velocity (in the fluid it is the fluid velocity, and it is
   continuous across the interface). With a pore pressure ``pi`` (P1 on the biofilm,
   its own space) and ``F^-T grad pi`` the spatial gradient, the equations in the
   biofilm are, on the reference domain,

   * Darcy, tested with the displacement test function ``w`` (the rows that hold
     ``u = 0`` in the base model)::

         int_s  u . w + (k/mu) (F^-T grad pi) . w  dX = 0

     so that ``k = 0`` is exactly the base model's kinematic form ``u = 0``;
   * mass balance of the incompressible pore water, ``div_x u = 0``; with uniform k
     and Darcy's law this is ``div_x grad_x pi = 0``, written in the *k-free* form::

         int_s  J (F^-T grad pi) . (F^-T grad r) dX
               + (beta / h) int_interface (pi - p) r dS = 0

     (``r`` the test function of ``pi``), with the natural condition ``grad pi . n = 0``
     on the clamped base (impermeable substratum) and continuity of pressure
     ``pi = p`` on the interface, imposed by the penalty of weight ``beta / h``
     (``beta`` = :data:`PORE_PENALTY`, ``h`` the interface mesh size: ``pi - p`` is
     ``(h / beta)`` times the normal derivative: 4e-5 relative in the porous-block
     test). The discrete ``u`` is Darcy's velocity of the discrete ``pi`` projected
     on P2 by the ``w`` rows, so its divergence vanishes up to the discretization
     error (exactly for a linear ``pi``).
     Because the form does not contain k, the pore pressure is determined at ``k = 0``
     too (the harmonic extension of the interface pressure); it only ever feeds back
     through the two terms that vanish at ``phi = 0``. The fluid's own mass rows are
     not touched: ``div u = 0`` holds in the fluid by itself;
   * momentum of the mixture (total stress, Terzaghi, Biot coefficient 1:
     incompressible grains and water), tested with ``v``::

         int_s  P(F) : grad v - c pi J tr(grad v F^-1)  dX

     with ``c = 1`` for ``k > 0`` and ``c = 0`` at ``k = 0``. The fluid's pressure
     term ``- p J tr(grad v F^-1)`` has the same form, so with ``pi = p`` on the
     interface the skeleton carries the viscous traction of the flow on its surface
     and the pore-pressure gradient (the Darcy drag ``(mu/k) u = - grad pi``) in its
     volume.

   Interface conditions (Stokes–Darcy): the velocity is continuous (normal flux
   continuity, and the tangential velocity equal to the Darcy velocity: the
   Beavers–Joseph slip length ``sqrt(k)/alpha_BJ``, with ``alpha_BJ`` of order 1, is
   10 um at k = 100 um^2, below the interface mesh size (17-35 um), so slip is
   neither resolved nor modelled); the pressure is continuous
   (the viscous normal stress of the flow at a nearly no-slip wall is left out of the
   normal-stress balance, as is usual for a Darcy block); the total traction is
   continuous (automatic, as in the base model). k is a constant of the skeleton (no
   Kozeny–Carman dependence on the deformation).

   Why ``c`` is a switch. In a *steady* state any permeable skeleton is drained: the
   pore pressure has equilibrated with the flow whatever the value of k > 0 (the
   consolidation time ``L^2 mu / (k E)``, 0.2 s for L = 0.3 mm, k = 1 um^2 and
   E = 400 Pa, minutes for 1e-3 um^2, is over);
   only the flux through the biofilm scales with k. As ``k -> 0+`` the model tends
   to a drained biofilm without through-flow, whose skeleton takes the pressure of
   the flow as a body force in its volume (the pore-pressure gradient) instead of as a
   traction on its surface, and no longer feels the ambient (mean) pressure that
   compresses the base model's compressible solid; the base model is the
   impermeable solid. The candidate is therefore nested as the
   attachment is: ``phi = 0`` is the base model to round-off (same spaces as any other
   ``phi``; the pore pressure is solved and decoupled), and ``phi > 0`` adds the pore
   pressure's load at full strength. The step at ``phi -> 0+`` is physics of the
   steady state, not a numerical artefact: 5.8 um of interface shift at the ground
   truth. Flow through the biofilm then takes load off it once it is a sizeable part
   of the flow past the patch: less water is forced around it. Measured on the coarse
   mesh (E = 400 Pa, nu = 0.3, 100 mm^2/s), largest interface displacement: base
   27.5 um; k = 1e-3 um^2 (drained, no through-flow) 31.5 um; 1 um^2 31.5; 10 um^2
   31.6; 100 um^2 32.1 (largest interface velocity 9 mm/s); 1000 um^2 27.7 (53 mm/s);
   1e4 um^2 13.0 (102 mm/s); the paper mesh agrees to 0.2 um up to 3000 um^2 (the
   base model: 0.12 um). Up to ~100 um^2 the through-flow changes the displacement by
   2 % at most, and upwards; above, it decreases it fast. For permeabilities well
   below 100 um^2 the drained step is thus the larger part of the effect. Darcy's law
   is no longer valid when ``sqrt(k)`` nears the size of the patch (a Brinkman term
   would be needed): keep ``k`` well below 1e4 um^2 (``sqrt(k)`` = 0.1 mm).

   Switching the candidate on adds the pore-pressure space (a structural change: new
   state layout, 3 % more unknowns; a base state is embedded into it for a warm start,
   the pore pressure starting at zero). Cost per solve, ``bench_physics.py`` (noisy,
   loaded 2-core machine): 1.04 to 1.31 times the base model, cold or warm, coarse or
   paper mesh; timed phase by phase, +9 % at ``phi = 0`` on the coarse mesh. Newton
   needs as many iterations as the base model (7-9 from rest at the ground truth, up
   to 3000 um^2 on the paper mesh). Not combined with
   the attachment springs: ``permeability.phi > 0`` on their sliding base is a failed
   solve (:func:`unsupported_combination`).

The 3D model (``geometry.dim: 3``). The same classes and forms serve it, the dimension
read from the mesh, and all candidates are there
(:data:`bayescalib.models.fsi.model.PHYSICS_3D`): ``layer`` (the
indicator on ``y``, vertical in 3D too; ``cap`` is under the top of the colony),
``growth`` (``F_g = g I_3`` as in plane strain; ``F_e = F / g`` is the whole 3 x 3
tensor, ``J_e = det F / g^3``, the laws' 3D stresses at ``C_e = C / g^2`` with no
out-of-plane constants, ``P = g F S_e``), ``stiffening`` (``W`` the 3D energy),
``gravity`` (``-phi g e_y``, three components), ``inflow_skew`` (above) and
``permeability`` (the pore pressure P1 on the colony; unchanged forms; measured on
the 3D ``very_coarse`` mesh: nested to 1e-16 mm, the Darcy through-flow linear in k
in the drained regime) and ``attachment``. The springs act on both tangential
components of the base, ``+ int_base (d_x v_x + d_z v_z) / phi ds``, with ``d_y = 0``;
the floor's ALE mesh slides in x and z (:func:`bayescalib.models.fsi.model._sliding_base`);
the contact line is the base's rim, a curve, whose x- and z-velocity vertex and P2
edge DOFs are kept free (``MonolithicSolver._contact_line_dofs``; in 2D the two foot
points' x-velocity vertex DOFs). Checked against the 2D model: the ridge across the
width with slip side walls (the 2D problem extruded) on springs of 2e-4 mm/Pa slides
its feet by 7.29 and 2.42 um at the mid-plane on the 3D ``very_coarse`` mesh, the 2D
coarse model's by 7.16 and 2.26 um. As ``phi -> 0+`` the rim's slide falls in
proportion to ``phi``, but the interface stays 1.2e-5 mm (``very_coarse``; 0.96e-5
mm ``coarse``) from the clamp's, against 1e-6 mm in 2D. At any ``phi > 0`` the
discrete problem is another one: the floor's ALE mesh slides (Neumann instead of
Dirichlet in x and z: another mesh motion for the same continuum problem) and the
rim's velocity DOFs are free. Holding the floor's mesh, and with it the rim, at
1e-9 mm/Pa gives back the clamp to 1e-8 mm, so the step comes from these (not
separated further: a clamped rim with a sliding floor inverts elements). It is 3e-4
of the displacement, below the mesh error (0.4 um between ``very_coarse`` and
``coarse``), and a step of the discretization at ``phi -> 0+``: base solves are
training points of the extended model to that accuracy.
Measured on the 3D ``coarse`` mesh (``benchmarks/bench_physics3d.py``; E = 400 Pa,
nu = 0.3, 100 mm^3/s), largest interface displacement: base 34.4 um; at the typical
phi layer 27.3, growth 41.4, attachment 37.8, inflow_skew 32.0, stiffening 30.5,
gravity 34.4 (the interface moves by 0.07 um), permeability 36.7; each solve as many
Newton iterations as the base (8), and as long (12-17 s on one core), but growth at
0.1 (12 iterations, 28 s).

Loads and the continuation. The load factor of the solver's continuation scales the
inflow; the two candidates that deform the biofilm without any flow, growth (a
prestrain) and gravity (a body force), are loads too. A continuation that starts at
rest (the zero state, the exact solution at zero load) scales their ``phi`` with the
load factor (:meth:`SolidPhysics.set_load_factor`), so that a swelling patch is grown
in steps like the flow is ramped up; without that the first step would have to take
the whole prestrain, and the step halving could not help (at zero inflow it would
retry the same problem). A continuation from a converged state at another inflow rate
keeps them at full value, as that state was solved with them. The factor is 1 at the
end of every converged solve, so the solution is the same.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = [
    "CANDIDATES",
    "G_MM_S2",
    "PORE_PENALTY",
    "UM2",
    "Candidate",
    "SolidPhysics",
    "enabled_candidates",
    "physics_parameters",
    "physics_problem",
    "springs_active",
    "unsupported_combination",
]

#: standard gravity in mm/s^2
G_MM_S2 = 9810.0
#: um^2 -> mm^2 (the unit of the permeability phi)
UM2 = 1.0e-6
#: dimensionless weight of the interface penalty ``pi = p`` of the pore pressure
#: (weight ``PORE_PENALTY / h`` against the O(1) Laplace form of ``pi``): the pore
#: pressure misses the fluid's by ``(h / PORE_PENALTY) dpi/dn`` (1e-5 relative in the
#: flow cell). Not larger: the range of the Jacobian's entries (down to the ALE
#: weight, ~1e-10) costs the LU factorization its accuracy. At 1e8 the first Newton
#: increment on the paper mesh was 1e6 times too large (24 instead of 9 iterations at
#: k = 0); at 1e6 the attachment springs with the candidate on at k = 0 failed
PORE_PENALTY = 1.0e4
#: a moderate permeability, um^2 (typical step of the candidate)
TYPICAL_K = 100.0


@dataclass(frozen=True)
class Candidate:
    """Description of one candidate effect.

    Attributes
    ----------
    name
        Config name (``physics.<name>``).
    unit
        Unit of ``phi`` in the config.
    summary
        One line in plain words for reports.
    typical
        A moderate value of ``phi`` (used for benchmarks and finite-difference steps).
    lo, hi
        Admissible range of ``phi`` (the schema's bounds; ``None`` = unbounded).
    continuous
        Whether the model is continuous in ``phi`` at ``phi = 0`` (the base model). The
        permeable biofilm is not: ``phi -> 0+`` is the drained biofilm, a step away from
        the impermeable base model, so base solves are no training points of its
        extended model near ``phi = 0+``.
    """

    name: str
    unit: str
    summary: str
    typical: float
    lo: float | None
    hi: float | None
    continuous: bool = True

    @property
    def key(self) -> str:
        """Dotted config key of ``phi``."""
        return f"physics.{self.name}.phi"


CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    Candidate("layer", "-", "stiffer or softer layer at the base (or cap) of the biofilm, "
              "phi = ln(E_layer/E)", 1.0, -5.0, 5.0),
    Candidate("growth", "-", "isotropic growth/swelling prestrain, F_g = (1 + phi) I", 0.03,
              -0.5, 0.5),
    Candidate("attachment", "mm/Pa", "imperfect attachment: base held by tangential springs "
              "of compliance phi", 2.0e-4, 0.0, None),
    Candidate("inflow_skew", "-", "skewed inflow profile at the same volume rate", 0.3,
              -1.0, 1.0),
    Candidate("stiffening", "-", "Fung-type exponential strain stiffening", 20.0, 0.0, None),
    Candidate("gravity", "kg/m^3", "density mismatch biofilm - water (body force)", 50.0,
              None, None),
    Candidate("permeability", "um^2", "permeable (poroelastic) biofilm: Darcy flow through it "
              "with permeability phi, skeleton loaded by the pore pressure", TYPICAL_K, 0.0, None,
              continuous=False),
)}


def enabled_candidates(physics: Mapping[str, Any]) -> list[str]:
    """Names of the switched-on candidates of a validated ``physics`` section."""
    return [n for n in CANDIDATES if physics[n]["enabled"]]


def physics_problem(physics: Mapping[str, Any], where: str = "physics") -> str:
    """Return a message if ``phi`` is non-zero for a switched-off candidate, else ``""``."""
    for name in CANDIDATES:
        sec = physics[name]
        if not sec["enabled"] and float(sec["phi"]) != 0.0:
            return (f"{where}.{name}.phi = {sec['phi']} but {where}.{name}.enabled is false: "
                    f"switch the candidate on or set phi to 0")
    return ""


def physics_parameters(physics: Mapping[str, Any]) -> dict[str, float]:
    """``{"physics.<name>.phi": phi}`` of the switched-on candidates (user units)."""
    return {CANDIDATES[n].key: float(physics[n]["phi"]) for n in enabled_candidates(physics)}


def springs_active(physics: Mapping[str, Any]) -> bool:
    """True when the attachment springs replace the clamp (enabled and ``phi > 0``)."""
    sec = physics["attachment"]
    return bool(sec["enabled"]) and float(sec["phi"]) > 0.0


def unsupported_combination(physics: Mapping[str, Any]) -> str:
    """A failure reason for candidate values the solver cannot combine, else ``""``.

    A permeable biofilm (``permeability.phi > 0``) on the sliding base of the
    attachment springs (``attachment.phi > 0``): Newton's first step from rest
    inverts elements at every load step (the linearization is near-singular: the
    base's tangential velocity is free for the springs and also Darcy's). Each of the
    two works with the other switched on at ``phi = 0``.
    """
    perm = physics["permeability"]
    if springs_active(physics) and perm["enabled"] and float(perm["phi"]) > 0:
        return (f"physics.permeability.phi = {perm['phi']} together with the attachment springs "
                f"(physics.attachment.phi = {physics['attachment']['phi']}) is not supported: "
                "the Darcy flow along the sliding base makes Newton's linearization singular")
    return ""


class SolidPhysics:
    """NGSolve parameters and coefficient functions of the switched-on candidates.

    Built once per compiled model (the structural part of the ``physics`` section);
    :meth:`set_values` puts the ``phi`` values of a solve into the parameters.

    Parameters
    ----------
    physics
        Validated ``physics`` section of the fsi config.
    patch_height
        Height of the biofilm patch, mm (for a cap layer).
    dim
        Space dimension of the problem (2 or 3): the number of components of the
        body force.
    """

    def __init__(self, physics: Mapping[str, Any], patch_height: float, dim: int = 2):
        import ngsolve as ng

        self.dim = int(dim)
        self.enabled = set(enabled_candidates(physics))
        self.layer_phi = ng.Parameter(0.0)
        self.growth_phi = ng.Parameter(0.0)
        self.stiffening_phi = ng.Parameter(0.0)
        self.gravity_phi = ng.Parameter(0.0)
        self.spring_stiffness = ng.Parameter(0.0)
        #: full values of the phi of growth and gravity (scaled by set_load_factor)
        self._loads: tuple[float, float] = (0.0, 0.0)
        #: Darcy mobility k/mu of the biofilm, mm^2/(mPa s) in solver units
        self.darcy_mobility = ng.Parameter(0.0)
        #: 1 when the pore pressure loads the skeleton (k > 0), 0 at k = 0
        self.pore_coupling = ng.Parameter(0.0)
        self.springs = springs_active(physics)
        self._layer_indicator = None
        if "layer" in self.enabled:
            sec = physics["layer"]
            t = float(sec["thickness"])
            if sec["where"] == "base":
                self._layer_indicator = ng.IfPos(t - ng.y, 1.0, 0.0)
            else:
                self._layer_indicator = ng.IfPos(ng.y - (patch_height - t), 1.0, 0.0)

    # ------------------------------------------------------------------ forms
    @property
    def permeable(self) -> bool:
        """True when the biofilm has a pore pressure (candidate ``permeability`` on)."""
        return "permeability" in self.enabled

    def stress_factor(self) -> Any:
        """Scalar factor on ``P`` from the stiffness layer (``None`` when off)."""
        import ngsolve as ng

        if self._layer_indicator is None:
            return None
        return ng.exp(self.layer_phi * self._layer_indicator)

    def growth(self) -> Any:
        """``phi`` of the growth candidate as a parameter (``None`` when off)."""
        return self.growth_phi if "growth" in self.enabled else None

    def stiffening(self) -> Any:
        """``phi`` of the stiffening candidate as a parameter (``None`` when off)."""
        return self.stiffening_phi if "stiffening" in self.enabled else None

    def body_force(self) -> Any:
        """Body force per reference volume on the solid (solver units), or ``None``."""
        import ngsolve as ng

        if "gravity" not in self.enabled:
            return None
        force = [0.0] * self.dim   # -phi g e_y: y is vertical in 2D and in 3D
        force[1] = -G_MM_S2 * 1.0e-3 * self.gravity_phi
        return ng.CoefficientFunction(tuple(force))

    # ------------------------------------------------------------------ values
    def set_values(self, physics: Mapping[str, Any], stress_unit: float,
                   viscosity: float = 1.0) -> None:
        """Set the parameters from the ``phi`` values of ``physics`` (user units).

        ``stress_unit`` converts Pa to solver stress units (spring stiffness Pa/mm);
        ``viscosity`` is the fluid's dynamic viscosity in solver units (mg/(mm s)), for
        the Darcy mobility ``k/mu``.
        """
        k = float(physics["permeability"]["phi"])
        if k < 0.0:
            raise ValueError(f"physics.permeability.phi = {k}: a permeability must be >= 0 um^2")
        self.darcy_mobility.Set(k * UM2 / float(viscosity))
        self.pore_coupling.Set(1.0 if k > 0.0 else 0.0)
        self.layer_phi.Set(float(physics["layer"]["phi"]))
        self.stiffening_phi.Set(float(physics["stiffening"]["phi"]))
        self._loads = (float(physics["growth"]["phi"]), float(physics["gravity"]["phi"]))
        self.set_load_factor(1.0)
        c = float(physics["attachment"]["phi"])
        self.spring_stiffness.Set(stress_unit / c if c > 0 else 0.0)

    def set_load_factor(self, factor: float) -> None:
        """Scale the candidates that load the solid without flow (growth, gravity).

        Sets their parameters to ``factor * phi`` with ``phi`` from the last
        :meth:`set_values`; ``factor = 1`` (the default state) is ``phi`` itself, to
        the bit. Used by the load continuation from rest.

        Parameters
        ----------
        factor
            Fraction of the full value, in [0, 1].
        """
        growth, gravity = self._loads
        self.growth_phi.Set(float(factor) * growth)
        self.gravity_phi.Set(float(factor) * gravity)

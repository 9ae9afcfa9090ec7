"""Problem description consumed by the monolithic FSI solver core.

One solver core (:mod:`bayescalib.models.fsi.solver`) serves the biofilm flow cell and the
Turek–Hron validation benchmarks (FSI1, CSM1, CFD1). Everything that differs between
them — mesh, region and boundary names, boundary data, fluid and solid constants, body
force — is gathered in :class:`FSIProblem`. The core is unit-agnostic: all values of a
problem must be in one consistent unit system (the biofilm model uses mm, s, mg, so
that stresses are in mPa; the Turek–Hron problems use SI).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bayescalib.models.fsi.materials import LAWS


@dataclass
class FSIProblem:
    """Geometry, boundary conditions and constants of one steady FSI problem.

    Attributes
    ----------
    mesh
        NGSolve mesh (already curved if wanted), 2D (triangles) or 3D (tetrahedra); the
        forms are the same in both (:mod:`bayescalib.models.fsi.solver`).
    fluid
        Material name (regex) of the fluid region, or ``None`` for a solid-only problem.
    solids
        Mapping solid material name -> law (``"svk"`` or ``"neo_hooke"``); empty for a
        fluid-only problem (a rigid obstacle). E and nu are given per solve.
    velocity_dirichlet
        Boundary regex where the velocity is prescribed (zero, or the inflow profile on
        ``inflow``). It must include ``inflow``.
    displacement_dirichlet
        Boundary regex where the displacement (solid clamp and ALE mesh boundary) is zero.
    inflow
        Boundary name of the inflow, or ``None``.
    inflow_profile
        Callable returning the full-load inflow velocity as an NGSolve vector coefficient
        function of ``ngsolve.x, ngsolve.y`` (velocity units); scaled by the load factor.
    rho_fluid, mu_fluid
        Fluid density and dynamic viscosity.
    rho_solid
        Solid reference density (only used with ``body_force``).
    body_force
        Acceleration (gx, gy) — in 3D (gx, gy, gz) — acting on the solid, scaled by the
        load factor (CSM1 gravity, the 3D cantilever).
    interface
        Boundary name of the fluid–solid interface (output and checks), or ``None``.
    ale_weight
        Weight of the harmonic mesh-extension form in the fluid. It must be tiny against
        the solid's ``u = 0`` form it shares rows with on the interface, otherwise the
        interface slips (NOTES-fsi.md); see :attr:`length_scale`.
    length_scale
        Characteristic element size near the interface; the extension form is weighted by
        ``ale_weight * length_scale**2`` so that the ratio to the mass form is
        ``ale_weight`` whatever the units.
    order
        Polynomial order of velocity and displacement (pressure: ``order - 1``).
    viscous_form
        ``"gradient"`` (``mu grad u : grad v``; natural outflow condition "do nothing")
        or ``"symmetric"`` (``2 mu eps(u) : eps(v)``; natural condition: zero traction).
    physics
        Candidate physics of the solid (:class:`bayescalib.models.fsi.physics.SolidPhysics`):
        stress factor, growth, stiffening, body force, base springs, a permeable solid
        with a pore pressure (needs ``fluid`` and ``interface``); ``None`` for none.
    velocity_dirichlet_xy, displacement_dirichlet_xy
        Component-wise Dirichlet boundaries ``(x regex, y regex)`` — in 3D
        ``(x regex, y regex, z regex)``; when given they replace ``velocity_dirichlet`` /
        ``displacement_dirichlet`` (e.g. a base that may slide tangentially, or the
        symmetry walls ``z = const`` of the 3D channel).
    spring_boundary
        Boundary on the floor (normal y) with tangential springs of stiffness
        ``physics.spring_stiffness`` (traction ``-k d_x``, in 3D also ``-k d_z``), or
        ``None``.
    compile
        ``"tree"`` (``CoefficientFunction.Compile()``, default), ``"none"``, or ``"real"``
        (compile to C++; needs a compiler, slow first build).
    """

    mesh: Any
    fluid: str | None
    solids: dict[str, str]
    velocity_dirichlet: str
    displacement_dirichlet: str
    inflow: str | None = None
    inflow_profile: Callable[[], Any] | None = None
    rho_fluid: float = 1.0
    mu_fluid: float = 1.0
    rho_solid: float = 1.0
    body_force: tuple[float, ...] = (0.0, 0.0)
    interface: str | None = None
    ale_weight: float = 1e-6
    length_scale: float = 1.0
    order: int = 2
    viscous_form: str = "gradient"
    compile: str = "tree"
    physics: Any = None
    velocity_dirichlet_xy: tuple[str, ...] | None = None
    displacement_dirichlet_xy: tuple[str, ...] | None = None
    spring_boundary: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, law in self.solids.items():
            if law not in LAWS:
                raise ValueError(f"solid region '{name}': unknown law '{law}', expected one of {LAWS}")
        if self.fluid is None and not self.solids:
            raise ValueError("an FSI problem needs a fluid region, solid regions, or both")
        if self.inflow is not None and self.inflow_profile is None:
            raise ValueError("inflow boundary given without an inflow profile")
        if self.viscous_form not in ("gradient", "symmetric"):
            raise ValueError(f"viscous_form must be 'gradient' or 'symmetric', got {self.viscous_form!r}")
        if self.spring_boundary is not None and self.physics is None:
            raise ValueError("spring_boundary needs physics with a spring stiffness")
        if self.order < 2:
            raise ValueError("order must be >= 2 (Taylor–Hood P2/P1)")

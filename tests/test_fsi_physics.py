"""Candidate physics of the FSI model (bayescalib.models.fsi.physics): nestedness and the
defining behaviour of each candidate, on the coarse mesh (32 interface nodes).

Tolerances. Nestedness is exact by construction (a factor exp(0) = 1, a zero term, or
the base clamp itself), so phi = 0 must agree with the base model to round-off: 1e-10
mm, far below the Newton tolerance (displacement increments of 1e-9 mm + 1e-5
relative). The mesh error of the interface displacement is about 1e-4 mm
(NOTES-fsi.md, and tests/test_fsi_biofilm.py); a candidate "changes the interface by
well above the mesh error" when its effect at the typical phi exceeds 10x that.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ngsolve")

from bayescalib.config import ConfigError
from bayescalib.models.fsi.model import FSIModel
from bayescalib.models.fsi.physics import CANDIDATES

COARSE = {"mesh": {"preset": "coarse"}}
TRUTH = {"material.E": 400.0, "material.nu": 0.3}
MESH_ERROR_MM = 1.0e-4


def _model(name: str, **settings) -> FSIModel:
    return FSIModel({**COARSE, "physics": {name: {"enabled": True, **settings}}})


def _shift(a, b) -> float:
    """Largest node distance between two interfaces of the same mesh, mm."""
    return float(np.max(np.hypot(*(a.interface_current - b.interface_current).T)))


@pytest.fixture(scope="module")
def base():
    return FSIModel(COARSE).solve(TRUTH)


@pytest.fixture(scope="module")
def base_at_rest():
    return FSIModel(COARSE).solve({**TRUTH, "inflow.rate": 0.0})


@pytest.mark.parametrize("name", sorted(CANDIDATES))
def test_candidate_at_phi_zero_is_the_base_model(base, name):
    res = _model(name).solve(TRUTH)
    assert res.ok, res.reason
    assert _shift(res, base) < 1e-10
    assert res.parameters[CANDIDATES[name].key] == 0.0


@pytest.mark.parametrize("name", sorted(set(CANDIDATES) - {"gravity"}))
def test_candidate_at_typical_phi_moves_the_interface_well_above_the_mesh_error(base, name):
    phi = CANDIDATES[name].typical
    res = _model(name).solve({**TRUTH, CANDIDATES[name].key: phi})
    assert res.ok, res.reason
    assert _shift(res, base) > 10 * MESH_ERROR_MM


def test_gravity_is_a_tiny_effect_linear_in_the_density_excess(base_at_rest):
    # negative control: 50 kg/m^3 excess density sags the patch by less than the mesh
    # error; at rest the sag is linear in phi (small strain): 2 phi -> 2x (1 %)
    m = _model("gravity")
    r1 = m.solve({**TRUTH, "inflow.rate": 0.0, "physics.gravity.phi": 50.0})
    r2 = m.solve({**TRUTH, "inflow.rate": 0.0, "physics.gravity.phi": 100.0})
    d1 = r1.interface_current - base_at_rest.interface_current
    d2 = r2.interface_current - base_at_rest.interface_current
    apex = int(np.argmax(base_at_rest.interface_reference[:, 1]))
    assert d1[apex, 1] < 0.0  # heavier than water: sags
    assert np.max(np.abs(d1)) < MESH_ERROR_MM
    np.testing.assert_allclose(d2, 2.0 * d1, rtol=0.01, atol=0.01 * np.max(np.abs(d1)))


def test_growth_changes_the_shape_with_zero_flow(base_at_rest):
    m = _model("growth")
    ref = base_at_rest.interface_reference
    apex = int(np.argmax(ref[:, 1]))
    h = ref[apex, 1]
    assert np.max(np.abs(base_at_rest.interface_current - ref)) < 1e-12  # base: no flow, no motion
    up = m.solve({**TRUTH, "inflow.rate": 0.0, "physics.growth.phi": 0.03})
    down = m.solve({**TRUTH, "inflow.rate": 0.0, "physics.growth.phi": -0.03})
    rise_up = up.interface_current[apex, 1] - h
    rise_down = down.interface_current[apex, 1] - h
    # a free layer would rise by phi h = 0.012 mm; the clamped base restrains the
    # in-plane growth and the Poisson effect pushes the apex further up: same sign,
    # same order of magnitude
    assert 0.5 * 0.03 * h < rise_up < 3.0 * 0.03 * h
    assert rise_down < 0.0 and abs(rise_down + rise_up) < 0.2 * rise_up  # odd to first order


def test_stiff_base_layer_reduces_and_soft_layer_increases_the_displacement(base):
    m = _model("layer", where="base", thickness=0.1)
    stiff = m.solve({**TRUTH, "physics.layer.phi": 1.0})
    soft = m.solve({**TRUTH, "physics.layer.phi": -1.0})
    assert stiff.max_displacement < base.max_displacement < soft.max_displacement


def test_cap_layer_acts_on_the_top_of_the_patch(base):
    m = _model("layer", where="cap", thickness=0.1)
    stiff = m.solve({**TRUTH, "physics.layer.phi": 1.0})
    assert stiff.max_displacement < base.max_displacement


def test_springs_let_the_base_slide_downstream_and_tend_to_the_clamp(base):
    m = _model("attachment")
    soft = m.solve({**TRUTH, "physics.attachment.phi": 4.0e-4})
    stiff = m.solve({**TRUTH, "physics.attachment.phi": 1.0e-4})
    stiffer = m.solve({**TRUTH, "physics.attachment.phi": 2.5e-5})
    feet = [0, -1]
    for res in (soft, stiff, stiffer):
        assert res.ok, res.reason
    slide = [(r.interface_current - r.interface_reference)[feet, 0] for r in (soft, stiff, stiffer)]
    clamped = (base.interface_current - base.interface_reference)[feet, 0]
    assert np.all(np.abs(clamped) < 1e-12)
    assert np.all(slide[0] > 0)  # the flow drags the base downstream
    assert np.all(slide[0] > slide[1]) and np.all(slide[1] > slide[2])
    # towards the clamp as the compliance -> 0: the distance to the base model shrinks
    assert _shift(stiffer, base) < _shift(stiff, base) < _shift(soft, base)


def test_stiff_springs_solve_and_their_feet_follow_the_springs_to_the_clamp(base):
    """The base's end points (where the sliding base meets the no-slip floor) obey the
    solid's force balance with the springs, not the ALE extension: as the compliance
    falls the feet's slide falls in proportion (a spring: slide = phi x traction, with
    a traction that tends to the clamp's) and the interface tends to the clamp's,
    continuously. Before this was so, every solve at phi <= 1e-5 mm/Pa under flow failed
    with an inverted element at the upstream foot."""
    m = _model("attachment")
    runs = {phi: m.solve({**TRUTH, "physics.attachment.phi": phi})
            for phi in (1.0e-5, 1.0e-6, 1.0e-7, 1.0e-9)}
    for phi, res in runs.items():
        assert res.ok, (phi, res.reason)
    feet = [0, -1]
    slide = {phi: (r.interface_current - r.interface_reference)[feet, 0]
             for phi, r in runs.items()}
    assert np.all(slide[1.0e-6] > 0)
    # nearly linear in phi (0.12 um of slide at 1e-6 mm/Pa against 35 um elements): the
    # ratio at 1e-7 / 1e-6 within 25 % of 0.1. Not closer: the foot is a corner of
    # singular stress whose traction the slide itself relaxes (measured 0.109). A foot
    # set by the ALE extension instead slides about as far at any stiff compliance.
    np.testing.assert_allclose(slide[1.0e-7] / slide[1.0e-6], 0.1, rtol=0.25)
    shifts = [_shift(runs[phi], base) for phi in (1.0e-5, 1.0e-6, 1.0e-7, 1.0e-9)]
    assert shifts == sorted(shifts, reverse=True)
    # phi = 1e-9 mm/Pa: a slide of about 1e-7 um; within 1e-6 mm of the clamp (the
    # Newton tolerance, 1e-9 mm + 1e-5 relative of the 0.03 mm displacement, allows 3e-7)
    assert shifts[-1] < 1.0e-6


def test_skewed_inflow_towards_the_top_unloads_the_biofilm(base):
    m = _model("inflow_skew")
    up = m.solve({**TRUTH, "physics.inflow_skew.phi": 0.5})
    down = m.solve({**TRUTH, "physics.inflow_skew.phi": -0.5})
    assert up.max_displacement < base.max_displacement < down.max_displacement


def test_inflow_skew_keeps_the_volume_rate_and_shifts_the_flow_up():
    # flux of the solved velocity through the inlet: the skewed profile carries the same
    # volume rate (100 mm^2/s; P2 boundary data of a cubic profile, exact up to the
    # interpolation error, < 0.5 %) and, for phi > 0, more of it through the upper half
    import ngsolve as ng

    def fluxes(phi):
        m = _model("inflow_skew")
        assert m.solve({**TRUTH, "physics.inflow_skew.phi": phi}).ok
        ux = m.solver.gfu.components[0][0]
        inlet = m.solver.mesh.Boundaries("inlet")
        total = ng.Integrate(ux, m.solver.mesh, ng.BND, definedon=inlet)
        upper = ng.Integrate(ux * ng.IfPos(ng.y - 0.5, 1.0, 0.0), m.solver.mesh, ng.BND,
                             definedon=inlet, order=10)
        return total, upper

    t0, u0 = fluxes(0.0)
    t1, u1 = fluxes(0.5)
    assert t0 == pytest.approx(100.0, rel=5e-3) and t1 == pytest.approx(t0, rel=1e-6)
    assert u0 == pytest.approx(50.0, rel=0.05)
    # analytic share of the upper half for phi: 1/2 + 3 phi/16 (integral of the odd term)
    assert u1 / t1 == pytest.approx(0.5 + 3 * 0.5 / 16, abs=0.03)


def test_stiffening_reduces_the_displacement_more_at_higher_load():
    m = _model("stiffening")
    ratios = []
    for rate in (50.0, 100.0):
        lin = m.solve({**TRUTH, "inflow.rate": rate})
        st = m.solve({**TRUTH, "inflow.rate": rate, "physics.stiffening.phi": 20.0})
        assert st.ok and lin.ok
        ratios.append(st.max_displacement / lin.max_displacement)
    assert ratios[1] < ratios[0] < 1.0


# ----------------------------------------------------------------- permeable biofilm
# Drained reference: a permeability so small that the flow through the biofilm is
# negligible (interface velocities ~1e-4 mm/s against 100 mm/s in the channel) but the
# pore pressure already loads the skeleton: the k -> 0+ limit of the steady model.
K_DRAINED = 1.0e-3


def test_permeable_biofilm_at_phi_zero_decouples_the_pore_pressure(base, tmp_path):
    # the pore-pressure block is solved (the harmonic extension of the interface
    # pressure, finite) but feeds back into nothing: no flow, the base interface
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    m = _model("permeability")
    res = m.solve(TRUTH)
    assert res.ok, res.reason
    assert _shift(res, base) < 1e-10
    assert res.stats["ndof"] > base.stats["ndof"]  # the extra block is there
    assert res.stats["max_interface_velocity"] < 1e-6  # as the base: u = 0 on the interface
    pore = m.solver.block(m.solver.i_pore)
    assert np.all(np.isfinite(pore)) and np.max(np.abs(pore)) > 0.0
    # the VTU shows it as the pressure inside the biofilm (0 there for the base model)
    m.write_vtu(tmp_path / "f.vtu")
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(tmp_path / "f.vtu"))
    reader.Update()
    grid = reader.GetOutput()
    pres = vtk_to_numpy(grid.GetPointData().GetArray("pressure"))
    region = vtk_to_numpy(grid.GetCellData().GetArray("region"))
    cells = vtk_to_numpy(grid.GetCells().GetConnectivityArray()).reshape(-1, 3)
    inside = np.unique(cells[region != 0])
    assert np.max(np.abs(pres[inside])) > 0.0


def test_the_drained_limit_is_continuous_from_above_and_differs_from_the_base(base):
    # any k > 0 is drained in a steady state; the step at k = 0+ is physics (the
    # skeleton no longer carries the ambient pressure), the model is smooth above it
    m = _model("permeability")
    small = m.solve({**TRUTH, "physics.permeability.phi": K_DRAINED})
    smaller = m.solve({**TRUTH, "physics.permeability.phi": 0.1 * K_DRAINED})
    assert small.ok and smaller.ok
    assert _shift(small, smaller) < 1e-7
    assert _shift(small, base) > 10 * MESH_ERROR_MM


def test_flow_through_the_biofilm_lowers_the_drag_driven_displacement():
    # more permeable -> more water through the patch instead of around it: larger
    # velocities on the interface, less load, a smaller displacement (monotone from
    # the drained, no-through-flow limit over the range where the flow through is
    # large; up to ~100 um^2 the through-flow changes the displacement by 2 % at most)
    m = _model("permeability")
    runs = [m.solve({**TRUTH, "physics.permeability.phi": k})
            for k in (K_DRAINED, 1000.0, 3000.0)]
    assert all(r.ok for r in runs)
    disp = [r.max_displacement for r in runs]
    vel = [r.stats["max_interface_velocity"] for r in runs]
    assert disp[0] > disp[1] > disp[2]
    assert vel[0] < 1e-3 < vel[1] < vel[2]


def _darcy_block(k_um2: float, inflow: float):
    """Uniform flow ``inflow`` (mm/s) through a channel of height 0.5 mm with slip walls,
    filled over 1 <= x <= 1.5 mm by a rigid porous block (E = 1e9 Pa, held by stiff
    tangential springs on its walls, so that it neither moves nor deforms: 1e-8 mm).
    Exact solution: u = inflow everywhere, the pore pressure linear in the block,
    the pressure constant on either side; do-nothing outflow: p = 0 downstream."""
    import ngsolve as ng
    from netgen.occ import Glue, OCCGeometry, WorkPlane, X

    from bayescalib.config import validate
    from bayescalib.models.fsi.physics import SolidPhysics
    from bayescalib.models.fsi.problem import FSIProblem
    from bayescalib.models.fsi.solver import MonolithicSolver, SolverControls

    H, x0, L, h = 0.5, 1.0, 0.5, 0.1
    block = WorkPlane().MoveTo(x0, 0.0).Rectangle(L, H).Face()
    block.edges.name = "block_wall"
    block.edges.Min(X).name = "interface"
    block.edges.Max(X).name = "interface"
    block.faces.name = "block"
    channel = WorkPlane().Rectangle(2.5, H).Face()
    channel.edges.name = "wall"
    channel.edges.Min(X).name = "inlet"
    channel.edges.Max(X).name = "outlet"
    fluid = channel - block
    fluid.faces.name = "fluid"
    mesh = ng.Mesh(OCCGeometry(Glue([fluid, block]), dim=2).GenerateMesh(maxh=h))
    physics = validate({"physics": {"permeability": {"enabled": True, "phi": k_um2}}},
                       "fsi")["physics"]
    sp = SolidPhysics(physics, H)
    problem = FSIProblem(
        mesh=mesh, fluid="fluid", solids={"block": "svk"},
        velocity_dirichlet="inlet|wall|block_wall",
        velocity_dirichlet_xy=("inlet", "inlet|wall|block_wall"),   # slip walls
        displacement_dirichlet="inlet|outlet|wall|block_wall",
        displacement_dirichlet_xy=("inlet|outlet", "inlet|outlet|wall|block_wall"),
        spring_boundary="block_wall",
        inflow="inlet", inflow_profile=lambda: ng.CoefficientFunction((inflow, 0.0)),
        interface="interface", length_scale=h, physics=sp)
    solver = MonolithicSolver(problem)
    solver.set_materials({"block": (1.0e12, 0.3)})  # 1e9 Pa in solver units (mPa)
    sp.set_values(physics, 1.0, viscosity=1.0)        # water: mu = 1 mg/(mm s)
    sp.spring_stiffness.Set(1.0e12)
    out = solver.solve(SolverControls())
    assert out.ok, out.reason
    u = solver.gfu.components[0]
    p = solver.gfu.components[solver.i_p]
    pore = solver.gfu.components[solver.i_pore]
    faces = mesh.Boundaries("interface")
    up = ng.IfPos(x0 + 0.5 * L - ng.x, 1.0, 0.0)  # the upstream face x = 1
    flux = ng.Integrate(u[0] * up, mesh, ng.BND, definedon=faces)
    p_up = ng.Integrate(p * up, mesh, ng.BND, definedon=faces) / H
    p_down = ng.Integrate(p * (1.0 - up), mesh, ng.BND, definedon=faces) / H
    mismatch = ng.Integrate((pore - p) ** 2, mesh, ng.BND, definedon=faces) ** 0.5
    return flux, p_up - p_down, mismatch, H, L


@pytest.mark.parametrize("k_um2", [10.0, 100.0])
def test_flux_through_a_porous_block_follows_darcys_law(k_um2):
    # flux through the interface = (k/mu) dp/L H, with dp the drop of the fluid
    # pressure across the block. The exact solution (constant velocity, linear pore
    # pressure, constant pressures) lies in the discrete spaces, so the only errors are
    # the interface penalty pi = p, which shifts the pore pressure by (h/beta) dpi/dn
    # on each face: pi - p = -(h/beta) dpi/dn, so the pore pressure drops by
    # dp / (1 + 2 h/(beta L)) (4e-5 less than dp, beta = PORE_PENALTY = 1e4), and
    # the block's residual deformation (1e-8 relative). Darcy's law with the fluid's
    # dp to 1e-4; with the penalty's correction, to 1e-7
    from bayescalib.models.fsi.physics import PORE_PENALTY

    flux, dp, mismatch, H, L = _darcy_block(k_um2, inflow=1.0)
    k_mm2, mu, h = k_um2 * 1.0e-6, 1.0, 0.1
    assert flux == pytest.approx(1.0 * H, rel=1e-9)  # mass conservation: the inflow
    assert flux == pytest.approx(k_mm2 / mu * dp / L * H, rel=1e-4)
    dpi = dp / (1.0 + 2.0 * h / (PORE_PENALTY * L))
    assert flux == pytest.approx(k_mm2 / mu * dpi / L * H, rel=1e-7)
    assert mismatch < 1e-4 * dp  # pore pressure = fluid pressure on the interface


def test_neo_hooke_with_growth_and_stiffening_is_nested():
    cfg = {**COARSE, "material": {"law": "neo_hooke"},
           "physics": {"growth": {"enabled": True}, "stiffening": {"enabled": True}}}
    plain = FSIModel({**COARSE, "material": {"law": "neo_hooke"}}).solve(TRUTH)
    both = FSIModel(cfg).solve(TRUTH)
    assert _shift(both, plain) < 1e-10
    grown = FSIModel(cfg).solve({**TRUTH, "inflow.rate": 0.0, "physics.growth.phi": 0.03})
    assert grown.ok and grown.max_displacement > 0.005


def test_phi_of_a_switched_off_candidate_is_an_error():
    with pytest.raises(ConfigError, match="physics.growth.enabled is false"):
        FSIModel(COARSE).solve({**TRUTH, "physics.growth.phi": 0.03})
    with pytest.raises(ConfigError, match="physics.layer.where"):
        FSIModel({**COARSE, "physics": {"layer": {"enabled": True, "where": "middle"}}})


# ----------------------------------------------------------------- several loadings
def test_a_series_of_loadings_equals_separate_solves():
    m = FSIModel(COARSE)
    series = m.solve_loadings(TRUTH, [0.0, 0.5, 1.0])
    for f, res in zip((0.0, 0.5, 1.0), series):
        single = FSIModel(COARSE).solve({**TRUTH, "inflow.rate": 100.0 * f})
        assert res.ok and res.parameters["inflow.rate"] == pytest.approx(100.0 * f)
        assert _shift(res, single) < 1e-8
    # the no-flow snapshot of the base model is the reference shape
    assert series[0].max_displacement < 1e-12


def test_series_from_a_warm_start_goes_down_and_up(tmp_path):
    m = FSIModel(COARSE)
    m.solve(TRUTH)
    m.save_state(tmp_path / "s.npz")
    series = m.solve_loadings(TRUTH, [1.5, 0.5, 1.0], warm_start=tmp_path / "s.npz")
    ref = FSIModel(COARSE).solve_loadings(TRUTH, [1.5, 0.5, 1.0])
    for a, b in zip(series, ref):
        assert a.ok and b.ok
        assert _shift(a, b) < 1e-8
    assert series[0].max_displacement > series[2].max_displacement > series[1].max_displacement


def test_permeable_biofilm_with_attachment_springs_fails_naming_both_keys(base):
    m = FSIModel({**COARSE, "physics": {"permeability": {"enabled": True},
                                        "attachment": {"enabled": True}}})
    res = m.solve({**TRUTH, "physics.permeability.phi": 100.0,
                   "physics.attachment.phi": 2.0e-4})
    assert not res.ok
    assert "physics.permeability.phi" in res.reason and "physics.attachment.phi" in res.reason
    # either one at phi = 0 is fine: springs alone, or the base with the pore pressure.
    # The systems differ (the pore-pressure block), so Newton takes other iterates and
    # they agree to its tolerance, not bitwise: 1e-8 mm (1e-5 um; 7e-10 mm was seen)
    springs = m.solve({**TRUTH, "physics.attachment.phi": 2.0e-4})
    alone = _model("attachment").solve({**TRUTH, "physics.attachment.phi": 2.0e-4})
    assert springs.ok and _shift(springs, alone) < 1e-8
    assert _shift(m.solve(TRUTH), base) < 1e-8


def test_a_base_state_warm_starts_the_permeable_biofilm(tmp_path):
    # the permeable model has an extra block (the pore pressure): a base state is
    # embedded with the pore pressure at zero and converges to the cold solution
    b = FSIModel(COARSE)
    b.solve(TRUTH)
    b.save_state(tmp_path / "base.npz")
    m = _model("permeability")
    cold = m.solve({**TRUTH, "physics.permeability.phi": 100.0})
    warm = _model("permeability").solve({**TRUTH, "physics.permeability.phi": 100.0},
                                        warm_start=tmp_path / "base.npz")
    assert cold.ok and warm.ok and warm.stats["warm_start"] == 1
    assert _shift(warm, cold) < 1e-6
    vector = _model("permeability").solve({**TRUTH, "physics.permeability.phi": 100.0},
                                          warm_start=b.last_state)
    assert vector.ok and _shift(vector, cold) < 1e-6


def test_a_base_state_warm_starts_a_model_with_candidate_physics(tmp_path, base):
    # the state layout depends on the mesh only: the base state at the prior centre
    # is a valid initial guess for every candidate (the diagnosis relies on it)
    b = FSIModel(COARSE)
    b.solve(TRUTH)
    b.save_state(tmp_path / "base.npz")
    m = _model("growth")
    res = m.solve({**TRUTH, "physics.growth.phi": 0.0}, warm_start=tmp_path / "base.npz")
    assert res.ok and res.stats["warm_start"] == 1
    assert _shift(res, base) < 1e-6


# ------------------------------------------- a warm-started series down to zero load
# The diagnosis solves its points (each candidate switched on) as a series of loadings
# [0, 0.5, 1] warm-started from the base state at the centre of the design box, a state
# of the base model at the nominal inflow. Nearly incompressible points (nu = 0.445)
# are the hard case of the growth candidate: a prestrain taken in one Newton step from
# rest inverts elements.
FACTORS = [0.0, 0.5, 1.0]
NEAR_INCOMPRESSIBLE = {"material.E": 316.0, "material.nu": 0.445}
BOX_CENTRE = {"material.E": 450.0, "material.nu": -0.175}  # the concealed studies' box
SERIES_TIME_LIMIT_S = 60.0  # the concealed studies' forward_model.time_limit_s
ATOL_D, RTOL_D = 1e-9, 1e-5  # Newton's displacement test (solver defaults), mm


@pytest.fixture(scope="module")
def box_centre_state(tmp_path_factory):
    path = tmp_path_factory.mktemp("warm") / "base_state.npz"
    m = FSIModel(COARSE)
    assert m.solve(BOX_CENTRE).ok
    m.save_state(path)
    return path


def test_growth_without_flow_is_grown_by_the_continuation_from_rest():
    # the load factor of the continuation from rest scales the prestrain too: at zero
    # inflow the halved steps are smaller prestrains, not the same problem again
    res = _model("growth").solve({**NEAR_INCOMPRESSIBLE, "inflow.rate": 0.0,
                                  "physics.growth.phi": CANDIDATES["growth"].typical})
    assert res.ok, res.reason
    assert res.load_steps > 1 and res.stats["failed_steps"]  # one full step was too much


@pytest.mark.parametrize("name", [n if n == "growth" else pytest.param(n, marks=pytest.mark.slow)
                                  for n in sorted(CANDIDATES)])  # growth: the hard case
def test_a_warm_series_down_to_zero_load_solves_and_equals_the_cold_series(
        box_centre_state, name):
    m = _model(name)
    point = {**NEAR_INCOMPRESSIBLE, CANDIDATES[name].key: CANDIDATES[name].typical}
    warm = m.solve_loadings(point, FACTORS, warm_start=box_centre_state,
                            time_limit=SERIES_TIME_LIMIT_S)
    cold = m.solve_loadings(point, FACTORS, time_limit=SERIES_TIME_LIMIT_S)
    for f, w, c in zip(FACTORS, warm, cold):
        assert w.ok, f"warm, load {f}: {w.reason}"
        assert c.ok, f"cold, load {f}: {c.reason}"
        # two converged solutions agree to within the Newton tolerance of each
        tol = 2.0 * (ATOL_D + RTOL_D * max(w.max_displacement, c.max_displacement))
        assert _shift(w, c) < tol



def test_a_warm_series_solves_its_zero_loading_first(box_centre_state, monkeypatch):
    # the zero loading needs no other one: solved first, it never waits for a slow
    # loading to use up the time limit of the series
    m = FSIModel(COARSE)
    rates = []
    solve = m.solve

    def recording(overrides=None, **kwargs):
        rates.append(overrides["inflow.rate"])
        return solve(overrides, **kwargs)

    monkeypatch.setattr(m, "solve", recording)
    assert all(r.ok for r in m.solve_loadings(TRUTH, [0.5, 1.0, 0.0],
                                              warm_start=box_centre_state))
    assert rates == [0.0, 100.0, 50.0]


def test_the_zero_loading_leaves_the_others_of_a_warm_series_unchanged_to_the_bit(
        box_centre_state):
    point = {**TRUTH, "physics.growth.phi": CANDIDATES["growth"].typical}
    with_zero = _model("growth").solve_loadings(point, FACTORS, warm_start=box_centre_state)
    without = _model("growth").solve_loadings(point, FACTORS[1:], warm_start=box_centre_state)
    for a, b in zip(with_zero[1:], without):
        assert a.ok and b.ok
        assert np.array_equal(a.interface_current, b.interface_current)


def test_the_interface_is_a_smooth_function_of_the_parameters():
    """The GP surrogate fits the log-likelihood with a tiny nugget (no noise term), which
    assumes the forward model has no solver noise: the interface must be a smooth function
    of E and nu, not one that jumps when Newton takes one iteration more. Along a line in
    (E, nu), 8 equal steps of 1.25 % in E and 0.0125 in nu, the k-th differences of a
    smooth response fall with k by about the step over the response's scale (measured:
    1.9e-4, 1.8e-6, 1.8e-7, 1.8e-8 mm for k = 1..4), while noise grows with k (the
    binomial weights add up to 2^k). Tolerance on the fourth differences 1e-7 mm: 5x the
    smooth value, 0.1 % of the mesh error, and at most 0.003 nats in a Gaussian
    log-likelihood of 32 nodes with 1 um noise. (The same holds for the log-likelihood of
    the heterogeneous study, 7-D, RKHS measure, 13 solves on a line through its best
    solve: along nu1 a quartic fit leaves residuals below 1e-4 nats; along E2 the second
    differences change smoothly, from -0.15 through -0.48 to +0.01 nats, with no jump.)"""
    t = np.linspace(-1.0, 1.0, 9)
    shapes = []
    for s in t:
        res = FSIModel(COARSE).solve({"material.E": 400.0 * (1 + 0.05 * s),
                                      "material.nu": 0.3 + 0.05 * s})
        assert res.ok, res.reason
        shapes.append(res.interface_current)
    U = np.stack(shapes)  # (9, nodes, 2)
    size = [float(np.abs(np.diff(U, k, axis=0)).max()) for k in (1, 2, 3, 4)]
    assert size[0] > 1e-4  # the line moves the interface
    assert size[0] > size[1] > size[2] > size[3]  # differences fall with their order
    assert size[3] < 1e-7

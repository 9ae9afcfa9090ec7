"""Candidate physics in the 3D model (``geometry.dim: 3``, ``very_coarse`` mesh).

The 3D model has all the candidates (:data:`bayescalib.models.fsi.model.PHYSICS_3D`),
through the same forms as the 2D model. For each: (a) nestedness, switched on at ``phi = 0`` it
is the base model; (b) its effect has the physical direction and size.

Nestedness tolerance: 1e-10 mm on the interface vertices (the base displacement is
34 um). At ``phi = 0`` the candidate's terms are a factor ``exp(0) = 1`` or
``(1 + 0)``, a zero body force, a zero inflow term, a decoupled pore pressure or (the
springs at ``phi = 0``) the clamp itself, so the
discrete equations are the base model's up to the round-off of differently compiled
expression trees (1e-16 relative), amplified by the Newton solves (condition number of
the Jacobian, ~1e6 or so): 1e-10 mm, 3e-9 of the displacement, is far above that and
far below any effect (the smallest here, gravity's, moves the colony top by 60 nm).
Measured: 0 for all but the permeability (1e-16 mm).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ngsolve")

from bayescalib.models.fsi.duct import duct_velocity
from bayescalib.models.fsi.model import PHYSICS_3D, FSIModel
from bayescalib.models.fsi.physics import G_MM_S2

CFG3 = {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"}}
TRUTH = {"material.E": 400.0, "material.nu": 0.3}
NESTED_MM = 1e-10


def _model(name: str | None = None) -> FSIModel:
    physics = {} if name is None else {name: {"enabled": True}}
    return FSIModel({**CFG3, "physics": physics})


def _rise(res) -> float:
    """How far the colony's top (its highest vertex) went up, mm."""
    return float(res.interface_current[:, 1].max() - res.interface_reference[:, 1].max())


@pytest.fixture(scope="module")
def base():
    model = _model()
    res = model.solve(TRUTH)
    assert res.ok, res.reason
    return model, res


@pytest.fixture(scope="module")
def models():
    """One model per candidate, built once (the mesh is rebuilt per model: 0.3 s)."""
    return {name: _model(name) for name in PHYSICS_3D}


@pytest.mark.parametrize("name", PHYSICS_3D)
def test_each_3d_candidate_at_phi_zero_is_the_base_model(name, base, models):
    _, ref = base
    res = models[name].solve({**TRUTH, f"physics.{name}.phi": 0.0})
    assert res.ok, res.reason
    assert np.abs(res.interface_current - ref.interface_current).max() <= NESTED_MM
    assert res.parameters[f"physics.{name}.phi"] == 0.0


@pytest.mark.parametrize("name, phi", [("layer", np.log(3.0)), ("stiffening", 20.0)])
def test_a_stiffer_base_layer_and_strain_stiffening_lower_the_displacement(name, phi, base,
                                                                          models):
    """A base layer three times stiffer (a quarter of the colony's height) and Fung
    stiffening at 20 (measured: 34.0 -> 26.3 and 30.1 um) lower the largest
    displacement by more than 5 %, and not by more than the stiffer layer alone could
    (a colony stiffer everywhere by 3 would move a third)."""
    _, ref = base
    res = models[name].solve({**TRUTH, f"physics.{name}.phi": phi})
    assert res.ok, res.reason
    assert ref.max_displacement / 3.0 < res.max_displacement < 0.95 * ref.max_displacement


def test_a_softer_base_layer_raises_the_displacement(base, models):
    _, ref = base
    res = models["layer"].solve({**TRUTH, "physics.layer.phi": -np.log(3.0)})
    assert res.ok, res.reason
    assert res.max_displacement > 1.1 * ref.max_displacement


def test_swelling_raises_the_colony_at_zero_flow(models):
    """Isotropic swelling by g = 1 + phi at no flow raises the top by between the free
    swelling's ``phi h`` and that of a layer confined laterally by the clamp,
    ``phi h (1 + nu)/(1 - nu)`` (measured 1.24 phi h for phi = 0.03, h the meshed
    colony's height); shrinking lowers it as much."""
    model = models["growth"]
    nu, phi = 0.3, 0.03
    up = model.solve({**TRUTH, "inflow.rate": 0.0, "physics.growth.phi": phi})
    assert up.ok, up.reason
    h = float(up.interface_reference[:, 1].max())
    assert phi * h < _rise(up) < phi * h * (1 + nu) / (1 - nu)
    down = model.solve({**TRUTH, "inflow.rate": 0.0, "physics.growth.phi": -phi})
    assert down.ok, down.reason
    assert -phi * h * (1 + nu) / (1 - nu) < _rise(down) < -phi * h


def test_a_heavier_colony_sinks_at_zero_flow_by_its_weight(models):
    """rho_b - rho_w = 50 kg/m^3 at no flow: the top goes down, by less than a column
    of the colony's height under its own weight in confined compression would,
    ``Delta rho g h^2 / (2 M)`` with ``M = E (1 - nu) / ((1 + nu)(1 - 2 nu))``
    (0.11 um; the half-ellipsoid is narrower at the top, so it carries less), and by
    more than a tenth of it. A lighter colony rises."""
    model = models["gravity"]
    h, E, nu = 0.4, 400.0e3, 0.3   # mm, mPa
    M = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    column = 50.0e-3 * G_MM_S2 * h * h / (2.0 * M)
    heavy = model.solve({**TRUTH, "inflow.rate": 0.0, "physics.gravity.phi": 50.0})
    assert heavy.ok, heavy.reason
    assert 0.1 * column < -_rise(heavy) < column
    light = model.solve({**TRUTH, "inflow.rate": 0.0, "physics.gravity.phi": -50.0})
    assert light.ok, light.reason
    assert _rise(light) > 0.1 * column


def test_the_duct_profile_times_the_odd_skew_carries_no_volume():
    """The continuous skew term: the duct profile is even about y = H/2, (2y/H - 1)
    odd, so their product integrates to zero over the section (a fine midpoint grid
    symmetric in y; 1e-12 of the profile's own integral)."""
    H, W, n = 1.0, 1.0, 400
    y = (np.arange(n) + 0.5) * H / n
    z = (np.arange(n) + 0.5) * W / n
    Y, Z = np.meshgrid(y, z, indexing="ij")
    u = duct_velocity(Y, Z, H, W)
    assert abs(np.sum(u * (2 * Y / H - 1))) < 1e-12 * np.sum(u)


def test_the_skewed_inflow_keeps_the_volume_rate_and_unloads_the_colony(base, models):
    """The volume rate through the inlet (- int u . n) of the solved state is the base
    model's to 1e-10: the discrete skew is made free of volume on the inlet mesh
    (which is not symmetric in y: the plain product carries 1e-3 of the rate on this
    mesh). phi > 0 shifts the flow to the top, away from the colony: less
    displacement (measured 34.0 -> 31.4 um at 0.3); phi < 0 more."""
    import ngsolve as ng

    base_model, ref = base
    model = models["inflow_skew"]
    rate0 = base_model.solver.inflow_rate()   # of its one solve, the fixture's
    up = model.solve({**TRUTH, "physics.inflow_skew.phi": 0.3})
    assert up.ok, up.reason
    assert model.solver.inflow_rate() == pytest.approx(rate0, rel=1e-10)
    assert abs(rate0 - 100.0) < 0.5   # the discrete duct profile: 0.14 % above the rate
    assert up.max_displacement < 0.95 * ref.max_displacement
    down = model.solve({**TRUTH, "physics.inflow_skew.phi": -0.3})
    assert down.ok, down.reason
    assert model.solver.inflow_rate() == pytest.approx(rate0, rel=1e-10)
    assert down.max_displacement > 1.05 * ref.max_displacement
    # the correction of the discrete skew is of the size of the discretization error
    s = model.solver
    unit = model._unit_inflow
    plain = s.inflow_values(s.problem.inflow_profile() * (2.0 * ng.y - 1.0))
    assert abs(s.inflow_rate(plain)) < 1e-2 * s.inflow_rate(unit)


def test_darcy_flow_through_a_permeable_colony_is_linear_in_k_when_drained(base, models):
    """Drained regime (k << 100 um^2): the skeleton's load does not depend on k (the
    interface moves by < 0.01 um from k = 1e-3 to 1 um^2), the through-flow
    (the interface's largest Darcy velocity) scales with k (a factor 1000 to 1 %),
    and the drained colony differs from the impermeable base model (the step of
    the candidate at k -> 0+: 2 um here)."""
    _, ref = base
    model = models["permeability"]
    small = model.solve({**TRUTH, "physics.permeability.phi": 1e-3})
    v_small = small.stats["max_interface_velocity"]
    large = model.solve({**TRUTH, "physics.permeability.phi": 1.0})
    v_large = large.stats["max_interface_velocity"]
    assert small.ok and large.ok, (small.reason, large.reason)
    assert np.abs(small.interface_current - large.interface_current).max() < 1e-5
    assert v_large / v_small == pytest.approx(1000.0, rel=1e-2)
    assert np.abs(small.interface_current - ref.interface_current).max() > 1e-3


def test_springs_let_the_base_slide_downstream_and_tend_to_the_clamp(base, models):
    """Springs of compliance 2e-4 mm/Pa: the base's rim (the interface vertices at
    y = 0) slides downstream everywhere (measured 2.5 to 7.5 um), and the colony moves
    more (34.0 -> 37.7 um). Stiffer springs: the slide falls in proportion to phi (a
    spring: slide = phi x traction; 0.103 from 1e-6 to 1e-7 mm/Pa) and the interface
    tends to the clamp's, to within 2e-5 mm: at any phi > 0 the floor's ALE mesh
    slides and the rim's velocity is free, another discretization of the same problem
    (measured 1.35e-5 mm at 1e-7 mm/Pa, 1.2e-5 at 1e-9; physics.py)."""
    _, ref = base
    model = models["attachment"]
    runs = {phi: model.solve({**TRUTH, "physics.attachment.phi": phi})
            for phi in (2.0e-4, 1.0e-6, 1.0e-7)}
    for phi, res in runs.items():
        assert res.ok, (phi, res.reason)
    rim = np.abs(runs[2.0e-4].interface_reference[:, 1]) < 1e-12
    assert rim.sum() >= 8
    slide = {phi: (r.interface_current - r.interface_reference)[rim] for phi, r in runs.items()}
    assert np.all(slide[2.0e-4][:, 0] > 1e-3)
    assert np.all(slide[2.0e-4][:, 1] == 0.0)        # no lift-off, no penetration
    assert runs[2.0e-4].max_displacement > 1.05 * ref.max_displacement
    ratio = slide[1.0e-7][:, 0].mean() / slide[1.0e-6][:, 0].mean()
    assert ratio == pytest.approx(0.1, rel=0.25)
    shifts = [np.abs(runs[phi].interface_current - ref.interface_current).max()
              for phi in (2.0e-4, 1.0e-6, 1.0e-7)]
    assert shifts == sorted(shifts, reverse=True)
    assert shifts[-1] < 2e-5


def test_a_ridge_on_springs_with_slip_walls_slides_its_feet_as_the_2d_model():
    """The ridge across the width with slip side walls is the 2D problem extruded: on
    springs of 2e-4 mm/Pa its mid-plane feet slide as the 2D coarse model's (measured
    7.29 and 2.42 um against 7.16 and 2.26: within 10 %), and the mid-plane interface
    is the 2D one within 8 % of the largest displacement (measured 4.8 %; the base
    model's plane limit is within 8.0 % on this mesh, tests/test_fsi3d.py)."""
    over = {"physics.attachment.phi": 2.0e-4}
    r2 = FSIModel({"mesh": {"preset": "coarse"},
                   "physics": {"attachment": {"enabled": True}}}).solve(over)
    m3 = FSIModel({"geometry": {"dim": 3, "shape": "ridge", "side_walls": "slip"},
                   "mesh": {"preset": "very_coarse"}, "physics": {"attachment": {"enabled": True}}})
    r3 = m3.solve(over)
    assert r2.ok and r3.ok, (r2.reason, r3.reason)
    d3, mesh = m3.solver.gfu.components[m3.solver.i_d], m3.solver.mesh
    mid = np.array([d3(mesh(float(x), float(y), 0.5)) for x, y in r2.interface_reference])
    disp2 = r2.interface_current - r2.interface_reference
    feet = [0, -1]
    assert np.all(disp2[feet, 0] > 1e-3)
    np.testing.assert_allclose(mid[feet, 0], disp2[feet, 0], rtol=0.1)
    assert np.linalg.norm(mid[:, :2] - disp2, axis=1).max() < 0.08 * r2.max_displacement


@pytest.mark.parametrize("law", ["svk", "neo_hooke"])
def test_the_3d_growth_stress_is_the_law_at_the_elastic_part(law):
    """In 3D, energy ``g^3 W(F / g)`` gives ``P = g^2 P_law(F / g)``: the stress at a
    3 x 3 F with growth equals g^2 times the law's stress at F_e = F / g, and free
    swelling F = g I is stress-free (the 3D formulas of ``materials.piola1``: F_e is
    the whole tensor, J_e = det F / g^3, no out-of-plane constants)."""
    import ngsolve as ng
    from netgen.occ import Box, OCCGeometry

    from bayescalib.models.fsi.materials import piola1

    mesh = ng.Mesh(OCCGeometry(Box((0, 0, 0), (1, 1, 1))).GenerateMesh(maxh=2.0))
    point = mesh(0.3, 0.3, 0.3)
    E, nu, phi = 4.0e5, 0.3, 0.07
    g = 1.0 + phi
    rng = np.random.default_rng(0)
    F = np.eye(3) + 0.1 * rng.standard_normal((3, 3))

    def stress(Fm, growth=None):
        cf = ng.CoefficientFunction(tuple(Fm.ravel()), dims=(3, 3))
        out = piola1(law, cf, E, nu, growth=growth)
        assert tuple(out.dims) == (3, 3)
        return np.array(out(point)).reshape(3, 3)

    grown = stress(F, ng.Parameter(phi))
    np.testing.assert_allclose(grown, g * g * stress(F / g), rtol=1e-12, atol=1e-9)
    assert np.abs(stress(g * np.eye(3), ng.Parameter(phi))).max() < 1e-9 * E
    assert np.abs(stress(g * np.eye(3))).max() > 1e-2 * E   # without growth: stressed

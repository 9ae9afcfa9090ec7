"""The 3D forward model (``geometry.dim: 3``) and its validation against analytic references.

Validation tolerances (measured figures in ``benchmarks/bench_fsi3d.py``):

* cantilever (solid alone, l/t = 10, nu = 0, maxh = t/2, P2 tetrahedra): the mean tip
  deflection is 0.04 % from Timoshenko's beam (0.008 % at maxh = t/3) and 0.76 % above
  Euler–Bernoulli, whose difference is the shear term 0.8 (t/l)^2 = 0.8 %. Tolerance
  0.3 % to Timoshenko: the beam theory itself misses 3D elasticity by O((t/l)^2 / 10)
  (the clamp's restraint of warping), and the discretization error on this mesh is
  below 0.1 %; and the deflection must exceed Euler–Bernoulli by 0.5–1 % (the shear
  term is there, at its size).
* duct (fluid alone, H = W = 1 mm, l = 2 mm, maxh = 0.25 mm): centreline velocity 0.33 %
  and pressure drop 0.35 % from the Fourier series (0.08 % / 0.09 % at maxh = 0.15 mm:
  the P2/P1 discretization error, falling like h^2.7). Tolerance 1 %.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ngsolve")

from bayescalib.config import ConfigError
from bayescalib.geometry.interface import Interface
from bayescalib.io.runrecord import read_run, write_run
from bayescalib.measures.currents import rkhs_distance
from bayescalib.models.forward import solve_points
from bayescalib.models.fsi.duct import duct_flow_rate, duct_velocity
from bayescalib.models.fsi.model import FSIModel
from bayescalib.models.fsi.validation3d import cantilever, duct_flow

CFG3 = {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"}}


def test_duct_series_matches_plane_poiseuille_and_its_own_quadrature():
    """Q of the series tends to H^3 W / 12 for a wide duct, and is the integral of u."""
    assert duct_flow_rate(1.0, 1e4) / 1e4 == pytest.approx(1.0 / 12.0, rel=1e-4)
    y = np.linspace(0.0, 1.0, 401)
    z = np.linspace(0.0, 2.0, 801)
    Y, Z = np.meshgrid(y, z, indexing="ij")
    u = duct_velocity(Y, Z, 1.0, 2.0)
    assert np.trapezoid(np.trapezoid(u, z), y) == pytest.approx(duct_flow_rate(1.0, 2.0), rel=1e-4)
    assert np.abs(u[0]).max() < 1e-12 and np.abs(u[:, 0]).max() < 1e-12
    # square duct: u_max = 0.2947 G a^2 / mu with half-side a (White, Table 3-2 / eq. 3-48)
    assert duct_velocity(np.array(0.5), np.array(0.5), 1.0, 1.0) == pytest.approx(
        0.29468 * 0.25, rel=1e-4)


def test_cantilever_against_timoshenko_and_euler_bernoulli():
    r = cantilever()
    assert r.ok
    assert r.deflection == pytest.approx(r.timoshenko, rel=3e-3)
    assert 1.005 < r.deflection / r.euler_bernoulli < 1.01


def test_duct_flow_against_the_series():
    r = duct_flow()
    assert r.ok
    assert r.centre_velocity == pytest.approx(r.centre_velocity_exact, rel=1e-2)
    assert r.pressure_drop == pytest.approx(r.pressure_drop_exact, rel=1e-2)


@pytest.fixture(scope="module")
def solved3d(tmp_path_factory):
    """One 3D point through the solve path (a forked solve process) and its record."""
    path = tmp_path_factory.mktemp("fsi3d") / "run.h5"
    fm = {"type": "fsi", "fsi": CFG3, "time_limit_s": 120.0}
    (res,) = solve_points(fm, [{"material.E": 400.0, "material.nu": 0.3}], [path])
    return res, path


def test_a_3d_point_through_solve_points_writes_a_surface_record(solved3d):
    res, path = solved3d
    assert res.ok, res.reason
    back = read_run(path)
    assert back.interface_current.shape[1] == 3 and back.segments.shape[1] == 3
    np.testing.assert_array_equal(back.interface_current, res.interface_current)
    np.testing.assert_array_equal(back.segments, res.segments)
    assert back.stats["dim"] == 3 and back.stats["n_interface_triangles"] == len(back.segments)
    # the base is clamped: vertices on the floor do not move
    floor = back.interface_reference[:, 1] < 1e-9
    assert floor.sum() >= 8
    np.testing.assert_allclose(back.interface_current[floor], back.interface_reference[floor],
                               atol=1e-12)
    # no slip on the interface, and a displacement of a plausible size (2D: 0.028 mm)
    assert back.stats["max_interface_velocity"] < 1e-4
    assert 1e-3 < back.max_displacement < 0.05
    # pushed downstream
    disp = back.interface_current - back.interface_reference
    assert disp[:, 0].mean() > 0


def test_the_3d_interface_is_a_surface_the_rkhs_measure_takes(solved3d):
    res, _ = solved3d
    ref = Interface.surface(res.interface_reference, res.segments)
    cur = Interface.surface(res.interface_current, res.segments)
    # normals into the fluid: up on average, outwards from the colony's centre
    centre = np.array([1.0, 0.0, 0.5])
    assert np.all(np.einsum("ij,ij->i", ref.normals, ref.centres - centre) > 0)
    # half the area of the ellipsoid with semi-axes (0.3, 0.4, 0.3) mm (Knud Thomsen's
    # formula, within 1.1 %); the flat triangles of the very coarse mesh miss 3 %
    a, b, c, p = 0.3, 0.4, 0.3, 1.6075
    half = 2.0 * np.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3.0) ** (1.0 / p)
    assert ref.total_measure == pytest.approx(half, rel=0.05)
    # the vertices lie on that ellipsoid, each semi-axis along its own direction (x: width / 2,
    # y: height, z: depth / 2; the area above cannot tell a = 0.3 from b = 0.4 apart)
    q = (((ref.points - centre) / np.array([a, b, c])) ** 2).sum(axis=1)
    np.testing.assert_allclose(q, 1.0, atol=1e-6)
    assert ref.total_measure < half
    assert rkhs_distance(cur, ref, 0.1) > 0.0
    # D = sqrt(<a,a> - 2 <a,a> + <a,a>): the terms are O(area^2) ~ 0.5 mm^4 and cancel to
    # round-off (torch's threaded sums reorder them), so D is ~sqrt(1e-16 x 0.5) ~ 1e-8 mm
    assert rkhs_distance(ref, ref, 0.1) == pytest.approx(0.0, abs=1e-7)


def test_3d_runs_are_written_and_read_with_triangles(tmp_path, solved3d):
    res, _ = solved3d
    write_run(tmp_path / "again.h5", res)
    import h5py

    with h5py.File(tmp_path / "again.h5") as f:
        assert "triangles" in f["interface"] and "segments" not in f["interface"]


@pytest.mark.parametrize("override, match", [
    ({"mesh": {"preset": "fine"}}, "no 3D preset 'fine'"),
    ({"geometry": {"dim": 3, "shape": "polyline"}}, "half_ellipse, ridge and scan shapes only"),
    ({"geometry": {"dim": 3, "subdomains": {"enabled": True}}}, "subdomains"),
])
def test_what_the_3d_model_does_not_have_is_a_config_error(override, match):
    cfg = {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"}}
    for k, v in override.items():
        cfg[k] = {**cfg.get(k, {}), **v}
    with pytest.raises(ConfigError, match=match):
        FSIModel(cfg)


def test_a_colony_outside_the_channel_is_a_failed_build():
    with pytest.raises(ValueError, match="must lie inside the channel"):
        FSIModel({**CFG3, "geometry": {"dim": 3, "depth": 1.2}}).solve()


def test_nu_one_half_is_a_failed_3d_run_not_an_exception():
    res = FSIModel(CFG3).solve({"material.nu": 0.5})
    assert not res.ok and "Poisson" in res.reason
    assert res.interface_current.shape[1] == 3


@pytest.mark.slow
def test_slip_side_walls_and_neo_hooke_solve():
    res = FSIModel({"geometry": {"dim": 3, "side_walls": "slip"}, "mesh": {"preset": "very_coarse"},
                    "material": {"law": "neo_hooke"}}).solve()
    assert res.ok, res.reason
    assert res.stats["max_interface_velocity"] < 1e-4


def _plane_limit_checks(r, rel_difference):
    assert r.ok
    assert r.max_difference < rel_difference * r.max_displacement_2d
    assert r.max_out_of_plane < 0.015 * r.max_displacement_2d
    assert r.max_z_variation < 0.03 * r.max_displacement_2d


def test_the_extruded_ridge_with_slip_walls_tends_to_the_2d_model():
    """Measured: mid-plane displacement 8.0 % (of the 2D maximum, 0.0275 mm) from the 2D
    coarse model on the very coarse 3D mesh, 4.1 % on the coarse one (the 3D interface
    mesh, 0.15 and 0.08 mm against 0.035 mm in 2D, dominates); |d_z| 0.7 % and 0.5 %;
    the variation along z 2.1 % and 0.9 %. Tolerances: 12 %, 1.5 %, 3 %."""
    from bayescalib.models.fsi.validation3d import plane_limit

    _plane_limit_checks(plane_limit({"preset": "very_coarse"}, {"preset": "coarse"}), 0.12)


@pytest.mark.slow
def test_the_extruded_ridge_on_the_coarse_mesh_is_closer_to_the_2d_model():
    from bayescalib.models.fsi.validation3d import plane_limit

    _plane_limit_checks(plane_limit({"preset": "coarse"}, {"preset": "coarse"}), 0.06)


def test_a_ridge_is_3d_only():
    with pytest.raises(ConfigError, match="ridge is a 3D shape"):
        FSIModel({"geometry": {"shape": "ridge"}})


@pytest.mark.parametrize("cfg, key, base_key", [
    ({}, "08ea6d3dec7a3b19", "08ea6d3dec7a3b19"),
    ({"mesh": {"preset": "coarse"}}, "9fd66261d542c096", "9fd66261d542c096"),
    ({"geometry": {"width": 0.5}, "physics": {"permeability": {"enabled": True}}},
     "824fbe51401fd016", "9b0f6c49428e27fd"),
])
def test_2d_saved_states_keep_the_keys_they_had_before_the_3d_model(cfg, key, base_key):
    """A 2D state's key leaves out the 3D-only geometry keys, so the warm-start states
    that 2D studies saved before the 3D model existed are still taken (the keys are
    those of commit bed5275, computed there)."""
    from bayescalib.config import validate
    from bayescalib.models.fsi.model import _space_key

    v = validate(cfg, "fsi")
    assert (_space_key(v), _space_key(v, base=True)) == (key, base_key)
    v3 = validate({**cfg, "geometry": {**cfg.get("geometry", {}), "dim": 3}}, "fsi")
    assert _space_key(v3) != key  # a 3D mesh is another state layout

"""Tests of the discrepancy measures (eq:eucliddist, eq:cppdist, eq:surfcurrontriang)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from _interface_shapes import arc, circle, icosphere, rotation2d, square
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ive

from bayescalib.geometry.interface import Interface
from bayescalib.measures import (
    MeasureError,
    MeasureOptionError,
    closest_point,
    compute,
    default_measurement_points,
    euclidean,
    rkhs,
)
from bayescalib.measures.currents import (
    current,
    current_field,
    field_grid,
    naive_rkhs_squared,
    rkhs_squared,
)

R, DR = 0.4, 0.01


def sagitta(r: float, n: int) -> float:
    """Max distance between a circle of radius r and its inscribed n-gon."""
    return r * (1 - math.cos(math.pi / n))


# ----------------------------------------------------------------------------- CPP
def test_cpp_concentric_circles():
    model, obs = circle(R, 60), circle(R + DR, 4000)
    res = closest_point(model, obs)
    # model nodes lie on radius R exactly; the observed 4000-gon deviates from the
    # circle by at most its sagitta (~2.5e-7 mm)
    tol = sagitta(R + DR, 4000) + 1e-12
    np.testing.assert_allclose(res.distances, -DR, atol=tol)  # model inside -> negative
    assert res.n == 60
    assert res.D == pytest.approx(DR * math.sqrt(60), abs=tol * math.sqrt(60))
    # swapped roles: nodes of the big circle are outside the small one (sign +)
    res2 = closest_point(circle(R + DR, 50), circle(R, 4000))
    np.testing.assert_allclose(res2.distances, DR, atol=sagitta(R, 4000) + 1e-12)


def test_cpp_projects_onto_segments_not_vertices():
    obs = Interface.polyline([[0.0, 0.0], [1.0, 0.0]])
    model = Interface.polyline([[0.3, 0.2], [0.7, -0.1]])
    res = closest_point(model, obs)
    np.testing.assert_allclose(res.distances, [0.2, -0.1])  # nearest vertices are 0.36, 0.32 away


def test_cpp_sign_at_vertices():
    # an L-shaped observed curve (convex corner at (1,0)); a point beyond the corner
    obs = Interface.polyline([[0.0, 0.0], [1.0, 0.0], [1.0, -1.0]])  # normals +y, then +x
    model = Interface.polyline([[1.3, 0.4], [1.2, 0.5]])
    np.testing.assert_allclose(closest_point(model, obs).distances, [0.5, math.hypot(0.2, 0.5)])


def test_cpp_sphere_3d():
    model, obs = icosphere(1.0, 2), icosphere(1.1, 4)
    res = closest_point(model, obs)
    # the level-4 icosphere (edge ~0.08) lies within ~1e-3 of the sphere radius 1.1
    np.testing.assert_allclose(res.distances, -0.1, atol=2e-3)
    assert res.n == model.n_points


# ----------------------------------------------------------------------------- Euclidean
def test_euclidean_concentric_circles_along_normals():
    model, obs = circle(R, 3000), circle(R + DR, 3000)
    res = euclidean(model, obs, n_points=10)
    # measurement points are observed chord midpoints (inside the circle by < sagitta)
    tol = sagitta(R, 3000) + sagitta(R + DR, 3000)
    np.testing.assert_allclose(res.distances, -DR, atol=tol)
    assert res.n == 10 and res.D == pytest.approx(DR * math.sqrt(10), abs=tol * 4)


def test_euclidean_explicit_points_and_directions():
    obs = Interface.polyline([[0.0, 0.0], [2.0, 0.0]])
    model = Interface.polyline([[0.0, 0.1], [1.0, 0.3], [2.0, 0.1]])
    pts = np.array([[0.5, 0.0], [1.0, 0.0]])
    res = euclidean(model, obs, points=pts, directions=[[0.0, 2.0], [0.0, 1.0]])
    np.testing.assert_allclose(res.distances, [0.2, 0.3])
    # directions default to the observed normal
    np.testing.assert_allclose(euclidean(model, obs, points=pts).distances, [0.2, 0.3])
    # oblique direction: distance along the unit direction
    d = euclidean(model, obs, points=[[1.0, 0.0]], directions=[[1.0, 1.0]]).distances[0]
    # line (t/sqrt2, t/sqrt2) meets y = 0.3 - 0.2 (x - 1) for x >= 1 at x = 0.25/1.2 + 1 ... solve:
    x = 1.0 + (0.3 - 0.0) / (1.0 + 0.2) - 0.0
    assert d == pytest.approx(x * 0 + math.hypot(x - 1.0, x - 1.0), rel=1e-12)


def test_euclidean_miss_gives_finite_penalty_or_raises():
    obs = Interface.polyline([[0.0, 0.0], [2.0, 0.0]])
    model = Interface.polyline([[0.0, 0.1], [0.5, 0.1]])  # short: most normals miss it
    res = euclidean(model, obs, n_points=4)
    assert np.all(np.isfinite(res.distances)) and math.isfinite(res.D)
    diag = float(np.linalg.norm(np.ptp(np.vstack([model.points, obs.points]), axis=0)))
    assert res.distances[0] == pytest.approx(0.1)
    np.testing.assert_allclose(res.distances[1:], diag)
    assert res.D > euclidean(Interface.polyline([[0.0, 0.1], [2.0, 0.1]]), obs, n_points=4).D
    with pytest.raises(MeasureError, match="miss"):
        euclidean(model, obs, n_points=4, on_miss="raise")


def test_default_points_follow_displacement():
    ref = Interface.polyline(np.column_stack([np.linspace(0, 2, 201), np.zeros(201)]))
    x = np.linspace(0, 2, 201)
    bump = 0.05 * np.exp(-((x - 1.5) ** 2) / (2 * 0.1**2))
    obs = Interface.polyline(np.column_stack([x, bump]))
    pts, dirs = default_measurement_points(obs, 10, reference=ref)
    assert pts.shape == (10, 2)
    # all points where the displacement is >= 10 % of the max: |x - 1.5| <= 0.1 sqrt(2 ln 10)
    assert np.all(np.abs(pts[:, 0] - 1.5) <= 0.1 * math.sqrt(2 * math.log(10)) + 0.01)
    # spread over that region: both flanks of the bump are sampled
    assert pts[:, 0].min() < 1.4 and pts[:, 0].max() > 1.6
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    # without a reference: evenly spread by arc length
    pts0, _ = default_measurement_points(ref, 4)
    np.testing.assert_allclose(pts0[:, 0], [0.25, 0.75, 1.25, 1.75])


def test_euclidean_3d_planes_and_spheres():
    # ray-triangle path: shifted plane, default points by farthest-point sampling
    res = euclidean(square(1.0, 6, z=0.03), square(1.0, 4), n_points=5)
    np.testing.assert_allclose(res.distances, 0.03, atol=1e-12)  # flat: exact
    assert res.n == 5
    # spheres: the observed level-3 facet centres lie inside radius 1.1 by at most
    # ~1.1 * (1 - cos(edge/2R)) + facet sag, and the level-4 model by its own sag; < 4e-3
    res = euclidean(icosphere(1.0, 4), icosphere(1.1, 3), n_points=8)
    np.testing.assert_allclose(res.distances, -0.1, atol=4e-3)


# ----------------------------------------------------------------------------- RKHS
SW = 0.005


def test_rkhs_zero_for_identical_and_symmetric():
    a, b = arc(R, 61), arc(R + DR, 90)
    assert rkhs(a, a, SW).D == pytest.approx(0.0, abs=1e-7)
    assert rkhs(a, b, SW).D == pytest.approx(rkhs(b, a, SW).D, rel=1e-10)
    res = rkhs(a, b, SW)
    assert res.n == 1 and res.distances.shape == (1,)


def test_rkhs_invariant_to_rigid_motion():
    a, b = arc(R, 61), arc(R + DR, 90)
    Q, t = rotation2d(0.7), np.array([3.0, -1.0])
    d0 = rkhs(a, b, SW).D
    d1 = rkhs(a.transformed(Q, t), b.transformed(Q, t), SW).D
    assert d1 == pytest.approx(d0, rel=1e-9)


def test_rkhs_refined_copy_converges_to_zero():
    # without resampling, a curve and its refined copy differ by the quadrature error,
    # which vanishes as both are refined (fixed sigma_W)
    ds = []
    for n in (21, 81, 321):
        ds.append(rkhs(arc(R, n), arc(R, n).resampled(0.1 * R * math.pi / n), 0.05, spacing=math.inf).D)
    assert ds[0] > ds[1] > ds[2]
    assert ds[2] < 0.1 * ds[0]


def test_rkhs_grows_monotonically_with_offset():
    a = arc(R, 61)
    offsets = [0.0, 0.002, 0.005, 0.01, 0.02]
    values = [rkhs(a, arc(R + o, 61), SW).D for o in offsets]
    assert all(x < y for x, y in itertools.pairwise(values))


def test_rkhs_matches_naive_double_loop():
    rng = np.random.default_rng(3)
    a = Interface.polyline(np.cumsum(rng.uniform(0.01, 0.05, (12, 2)), axis=0))
    b = Interface.polyline(np.cumsum(rng.uniform(0.01, 0.05, (9, 2)), axis=0))
    sw = 0.03
    c1, a1 = current(a, sw, math.inf)
    c2, a2 = current(b, sw, math.inf)
    ref = naive_rkhs_squared(c1, a1, c2, a2, sw)
    for backend in ("numpy", "torch"):
        got = rkhs(a, b, sw, spacing=math.inf, backend=backend).D ** 2
        assert got == pytest.approx(ref, rel=1e-10)
    # and with truncation, blocking and symmetric self terms on a bigger random case
    x = rng.random((700, 3))
    ax = rng.normal(size=(700, 3))
    y = rng.random((500, 3))
    ay = rng.normal(size=(500, 3))
    dense = rkhs_squared(x, ax, y, ay, 0.05, backend="numpy", truncate=None)
    for backend in ("numpy", "torch"):
        blocked = rkhs_squared(x, ax, y, ay, 0.05, backend=backend, chunk=5000)
        np.testing.assert_allclose(blocked, dense, rtol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_rkhs_distance_is_the_l2_distance_of_the_square_root_smoothed_currents(dim):
    """The Gaussian kernel is the convolution of Gaussians of half its variance, so D^2 is
    the squared L2 norm of the difference of the currents smoothed by that half-width
    Gaussian: on a grid of spacing sigma_W / 2 the trapezoid rule gives it to about
    exp(-2 pi^2) = 3e-9 relative (tolerance 1e-7: the rule's aliasing error, with
    margin). The grid values are a residual vector of the RKHS measure."""
    if dim == 2:
        a, b, sw = arc(R, 61), arc(R + DR, 45, a0=0.1), 0.4 * R
    else:
        a, b, sw = icosphere(R, 1), icosphere(R + DR, 1), 0.8 * R
    c1, a1 = current(a, sw, math.inf)
    c2, a2 = current(b, sw, math.inf)
    s11, s12, s22 = rkhs_squared(c1, a1, c2, a2, sw, backend="numpy", truncate=None)
    both = np.vstack([c1, c2])
    grid, weight = field_grid(both.min(axis=0), both.max(axis=0), sw)
    residual = (current_field(c1, a1, sw, grid) - current_field(c2, a2, sw, grid)) * math.sqrt(weight)
    assert np.sum(residual**2) == pytest.approx(s11 - 2 * s12 + s22, rel=1e-7)
    # and each inner product alone: <a1, a1> as the square of one smoothed current
    self1 = np.sum(current_field(c1, a1, sw, grid) ** 2) * weight
    assert self1 == pytest.approx(s11, rel=1e-7)


def test_the_rkhs_field_residual_has_norm_d_and_one_length_for_every_model():
    """residual: field (what the output emulator learns). A model 2 sigma_W from the
    observed arc lies in the band (8 sigma_W): the grid part holds D^2 to the trapezoid
    rule's error at spacing 0.75 sigma_W (about 3e-4 relative; tolerance 1e-3) and the
    last entry is (nearly) 0. A model 10 sigma_W away lies partly outside: the last entry
    carries the rest, so |r| = D all the same (tolerance 1e-3). Every model gets a
    vector of the same length (the grid is the observed arc's), and the likelihood's D
    is the scalar measure's, bit for bit."""
    obs = arc(R, 81)
    lengths = set()
    for offset, inside in ((2 * SW, True), (10 * SW, False)):
        model = arc(R + offset, 57, a0=0.05)
        scalar = rkhs(obs=obs, model=model, sigma_w=SW)
        field = rkhs(obs=obs, model=model, sigma_w=SW, residual="field")
        assert field.D == scalar.D and field.n == 1
        r = field.distances
        lengths.add(r.size)
        assert np.linalg.norm(r) == pytest.approx(field.D, rel=1e-3)
        if inside:
            assert r[-1] < 0.03 * field.D
        else:
            assert r[-1] > 0.3 * field.D
    assert len(lengths) == 1
    with pytest.raises(MeasureOptionError, match="residual"):
        rkhs(obs, obs, SW, residual="grid")


def test_rkhs_numpy_and_torch_agree():
    a, b = arc(R, 61), arc(R + DR, 400)
    dn = rkhs(a, b, SW, backend="numpy").D
    dt = rkhs(a, b, SW, backend="torch").D
    d32 = rkhs(a, b, SW, backend="torch", dtype="float32").D
    assert dt == pytest.approx(dn, rel=1e-10)
    assert d32 == pytest.approx(dn, rel=1e-3)  # float32 kernel, float64 accumulation


def test_rkhs_discretization_independent_after_resampling():
    """The issue's case: half circle R = 0.4 mm, 61 vs 400 nodes, sigma_W = 0.005 mm."""
    coarse, fine = arc(R, 61), arc(R, 400)
    offset = rkhs(coarse, arc(R + DR, 400), SW).D
    same = rkhs(coarse, fine, SW).D
    raw = rkhs(coarse, fine, SW, spacing=math.inf).D
    # without resampling the two meshes of one curve look as different as a 0.01 mm offset
    assert raw > 0.3 * rkhs(coarse, arc(R + DR, 400), SW, spacing=math.inf).D
    # after resampling the remaining difference is the chord error of the 61-gon
    # (sagitta 1.3e-4 mm << 0.01 mm)
    assert same < 0.05 * offset
    # and the offset value no longer depends on which mesh carries the offset curve
    assert rkhs(fine, arc(R + DR, 61), SW).D == pytest.approx(offset, rel=0.05)


def circle_pair(r, s, sw):
    """<C_r, C_s>_V for concentric circles as continuous currents: 4 pi^2 r s e^{-(r-s)^2/2sw^2} I1e(rs/sw^2)."""
    return 4 * math.pi**2 * r * s * math.exp(-((r - s) ** 2) / (2 * sw**2)) * ive(1, r * s / sw**2)


def test_rkhs_concentric_circles_analytic():
    sw = 0.02
    r, s = 0.4, 0.43
    exact = circle_pair(r, r, sw) - 2 * circle_pair(r, s, sw) + circle_pair(s, s, sw)
    got = rkhs(circle(r, 2000), circle(s, 2000), sw).D ** 2
    # midpoint quadrature at spacing sw/4 (<= 0.3 %) and the 2000-gon (sagitta 5e-8 mm)
    assert got == pytest.approx(exact, rel=1e-2)


def sphere_pair(r, s, sw):
    """<S_r, S_s>_V for concentric spheres (outward unit normals times area)."""
    a = r * s / sw**2
    return 8 * math.pi**2 * r**2 * s**2 * (
        math.exp(-((r - s) ** 2) / (2 * sw**2)) * (1 / a - 1 / a**2)
        + math.exp(-((r + s) ** 2) / (2 * sw**2)) * (1 / a + 1 / a**2)
    )


def test_rkhs_spheres_analytic_3d():
    sw, r, s = 0.3, 1.0, 1.1
    exact = sphere_pair(r, r, sw) - 2 * sphere_pair(r, s, sw) + sphere_pair(s, s, sw)
    got = rkhs(icosphere(r, 4), icosphere(s, 4), sw, spacing=math.inf).D ** 2
    # flat level-4 facets (edge ~0.08 sw-relative 0.26): area/normal error ~1e-3,
    # midpoint quadrature ~0.3 %; together below 2 %
    assert got == pytest.approx(exact, rel=2e-2)


def test_rkhs_plane_vs_shifted_plane_3d():
    L, sw, delta = 0.1, 0.01, 0.01

    def f(L):  # int_0^L int_0^L exp(-(x-x')^2 / 2 sw^2)
        return 2 * sw**2 * (math.exp(-(L**2) / (2 * sw**2)) - 1) + math.sqrt(2 * math.pi) * sw * L * math.erf(
            L / (math.sqrt(2) * sw)
        )

    exact = 2 * f(L) ** 2 * (1 - math.exp(-(delta**2) / (2 * sw**2)))
    got = rkhs(square(L, 8), square(L, 5, z=delta), sw).D ** 2
    assert got == pytest.approx(exact, rel=1e-2)  # midpoint quadrature at sw/4


# ----------------------------------------------------------------------------- dispatcher
def test_compute_dispatch_and_errors():
    a, b = arc(R, 30), arc(R + DR, 40)
    assert compute("cpp", a, b).D == pytest.approx(closest_point(a, b).D)
    assert compute("rkhs", a, b, sigma_w=SW, spacing=None).D == pytest.approx(rkhs(a, b, SW).D)
    with pytest.raises(MeasureOptionError, match="unknown measure"):
        compute("hausdorff", a, b)
    with pytest.raises(MeasureOptionError, match="does not accept"):
        compute("cpp", a, b, sigma_w=0.1)
    with pytest.raises(MeasureOptionError, match="sigma_w"):
        compute("rkhs", a, b, sigma_w=-1.0)
    with pytest.raises(MeasureError, match="2D"):
        compute("cpp", a, icosphere(1.0, 0))


# ----------------------------------------------------------------------------- properties
polyline_pts = st.lists(
    st.tuples(st.floats(0.05, 0.3), st.floats(-0.2, 0.2)), min_size=2, max_size=12
).map(lambda d: np.cumsum(np.array(d), axis=0))


@settings(max_examples=25, deadline=None)
@given(polyline_pts, polyline_pts, st.floats(0.0, 6.3), st.floats(-1, 1), st.floats(-1, 1))
def test_rkhs_properties_random_polylines(p, q, angle, tx, ty):
    a, b = Interface.polyline(p), Interface.polyline(q)
    sw = 0.1
    d_ab = rkhs(a, b, sw, spacing=0.05).D
    assert math.isfinite(d_ab) and d_ab >= 0
    # D = sqrt(<a,a> - 2<a,b> + <b,b>): for (nearly) equal curves the rounding of the
    # O(1) inner products leaves sqrt(eps) ~ 1e-8 in D (hypothesis found 7.5e-9 against
    # 0 for curves 2e-16 apart), so symmetry holds to that floor, as a = a does below
    assert rkhs(b, a, sw, spacing=0.05).D == pytest.approx(d_ab, rel=1e-8, abs=1e-6)
    assert rkhs(a, a, sw, spacing=0.05).D == pytest.approx(0.0, abs=1e-6)
    Q, t = rotation2d(angle), np.array([tx, ty])
    moved = rkhs(a.transformed(Q, t), b.transformed(Q, t), sw, spacing=0.05).D
    assert moved == pytest.approx(d_ab, rel=1e-6, abs=1e-8)


@settings(max_examples=25, deadline=None)
@given(polyline_pts, polyline_pts)
def test_cpp_euclidean_properties_random_polylines(p, q):
    a, b = Interface.polyline(p), Interface.polyline(q)
    assert closest_point(a, a).D == pytest.approx(0.0, abs=1e-12)
    res = closest_point(a, b)
    # a CPP distance never exceeds the distance to the nearest observed vertex
    nearest_vertex = np.min(np.linalg.norm(a.points[:, None] - b.points[None], axis=2), axis=1)
    assert np.all(np.abs(res.distances) <= nearest_vertex + 1e-12)
    e = euclidean(a, b, n_points=min(3, b.n_cells))
    assert np.all(np.isfinite(e.distances)) and math.isfinite(e.D)


def test_rkhs_refuses_pairwise_work_beyond_its_limit_before_doing_it():
    """A curve with 2,000,000 points would take many minutes of kernel sums: refused at
    once, naming the element counts and the limit; the same curve at a sensible
    density is measured."""
    import time

    from bayescalib.geometry.interface import Interface
    from bayescalib.measures import MeasureOptionError, compute

    t = np.linspace(0.0, np.pi, 2_000_000)
    dense = Interface.polyline(np.column_stack([1.0 + 0.3 * np.cos(t), 0.4 * np.sin(t)]))
    model = Interface.polyline(np.column_stack([1.0 + 0.3 * np.cos(t[::40_000]),
                                                0.4 * np.sin(t[::40_000])]))
    t0 = time.perf_counter()
    with pytest.raises(MeasureOptionError, match=r"kernel pairs .* measure.rkhs.max_pairs"):
        compute("rkhs", model, dense, sigma_w=0.005)
    assert time.perf_counter() - t0 < 30  # refused before the work, not after it
    sparse = Interface.polyline(np.asarray(dense.points)[::2000])
    assert np.isfinite(compute("rkhs", model, sparse, sigma_w=0.005).D)

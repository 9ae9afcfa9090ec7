"""Tests of the Interface type: construction, validation, geometry, resampling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _interface_shapes import arc, circle, icosphere
from hypothesis import given, settings
from hypothesis import strategies as st

from bayescalib.geometry.interface import Interface, InterfaceError, segment_intersections


def test_polyline_geometry_and_left_normal_convention():
    # upstream -> downstream over a floor patch: normals point up (into the fluid)
    c = Interface.polyline([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    assert c.dim == 2 and c.n_cells == 2
    np.testing.assert_allclose(c.centres, [[0.5, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(c.normals, [[0.0, 1.0], [-1.0, 0.0]])
    np.testing.assert_allclose(c.measures, [1.0, 2.0])
    assert c.total_measure == pytest.approx(3.0)
    np.testing.assert_allclose(c.arc_length(), [0.0, 1.0, 3.0])
    # a clockwise circle has outward normals
    circ = circle(1.0, 64)
    assert np.all(np.einsum("md,md->m", circ.normals, circ.centres) > 0)


def test_surface_geometry():
    s = Interface.surface([[0, 0, 0], [2, 0, 0], [0, 2, 0]], [[0, 1, 2]])
    np.testing.assert_allclose(s.normals, [[0, 0, 1]])
    np.testing.assert_allclose(s.measures, [2.0])
    np.testing.assert_allclose(s.centres, [[2 / 3, 2 / 3, 0]])
    # icosphere area converges to 4 pi R^2 (flat triangles: area deficit O(h^2), < 1 % at level 3)
    assert icosphere(1.0, 3).total_measure == pytest.approx(4 * math.pi, rel=1e-2)


@pytest.mark.parametrize(
    "points, cells, match",
    [
        ([[0.0, 0.0]], None, "at least 2 points"),
        (np.zeros((0, 2)), None, "at least 2 points"),
        ([[0.0, 0.0], [np.nan, 1.0]], None, "NaN/inf"),
        ([[0.0, 0.0], [np.inf, 1.0]], None, "NaN/inf"),
        ([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [2.0, 0.0]], None, "duplicate consecutive"),
        ([[0.0, 0.0], [1.0, 0.0]], [[0, 2]], "indices"),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [[0, 1]], "triangles"),
    ],
)
def test_invalid_interfaces_raise(points, cells, match):
    with pytest.raises(InterfaceError, match=match):
        pts = np.asarray(points, dtype=float)
        if cells is None:
            Interface.polyline(pts)
        else:
            Interface(pts, np.asarray(cells))


def test_degenerate_triangle_raises():
    with pytest.raises(InterfaceError, match="zero area"):
        Interface.surface([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]])


def test_arc_length_needs_ordered_curve():
    with pytest.raises(InterfaceError, match="ordered"):
        icosphere(1.0, 0).arc_length()


def test_curve_resampling_keeps_geometry_and_bounds_spacing():
    c = arc(0.4, 61)
    r = c.resampled(0.00125)
    assert r.is_chain()
    assert r.measures.max() <= 0.00125 * (1 + 1e-9)
    # same polyline: every original node is kept, length and current are unchanged
    assert r.total_measure == pytest.approx(c.total_measure, rel=1e-12)
    np.testing.assert_allclose(r.current.sum(axis=0), c.current.sum(axis=0), atol=1e-14)
    orig_in = np.isclose(np.linalg.norm(r.points[:, None] - c.points[None], axis=2), 0, atol=1e-12)
    assert orig_in.any(axis=0).all()
    # closed curves stay closed
    cc = circle(1.0, 16).resampled(0.05)
    assert cc.n_cells == cc.n_points and cc.is_chain()


def test_surface_resampling_bounds_edges_and_keeps_area():
    s = icosphere(1.0, 1)
    r = s.resampled(0.1)
    p = r.points[r.cells]
    edges = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
    assert edges.max() <= 0.1 * (1 + 1e-9)
    assert r.total_measure == pytest.approx(s.total_measure, rel=1e-12)
    np.testing.assert_allclose(r.current.sum(axis=0), s.current.sum(axis=0), atol=1e-12)
    # orientation preserved: every sub-triangle normal equals its parent's
    assert np.all(np.einsum("md,md->m", r.normals, r.centres) > 0)


def test_self_intersection_detection():
    bow = Interface.polyline([[0, 0], [1, 1], [1, 0], [0, 1]])
    assert segment_intersections(bow) == [(0, 2)]
    assert segment_intersections(arc(1.0, 50)) == []
    assert segment_intersections(circle(1.0, 50)) == []


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=2, max_size=30),
    st.floats(0.01, 2.0),
)
def test_random_polylines_valid_or_clear_error(pts, h):
    """Random input either builds a valid interface whose resampling keeps the length,
    or raises InterfaceError (duplicates) -- never anything else."""
    p = np.array(pts)
    try:
        c = Interface.polyline(p)
    except InterfaceError as exc:
        assert "duplicate" in str(exc) or "degenerate" in str(exc)
        return
    r = c.resampled(h)
    assert r.total_measure == pytest.approx(c.total_measure, rel=1e-9)
    assert r.measures.max() <= h * (1 + 1e-9)
    np.testing.assert_allclose(np.linalg.norm(r.normals, axis=1), 1.0)


def _brute_intersections(iface):
    """All intersecting non-adjacent segment pairs by the O(n^2) definition."""
    p = iface.points[iface.cells]
    a, b = p[:, 0], p[:, 1]

    def o(p_, q_, r_):
        return (q_[0] - p_[0]) * (r_[1] - p_[1]) - (q_[1] - p_[1]) * (r_[0] - p_[0])

    out = set()
    for i in range(len(p)):
        for j in range(i + 1, len(p)):
            if set(iface.cells[i]) & set(iface.cells[j]):
                continue
            if np.any(np.minimum(a[i], b[i]) > np.maximum(a[j], b[j])) or \
                    np.any(np.minimum(a[j], b[j]) > np.maximum(a[i], b[i])):
                continue
            if o(a[i], b[i], a[j]) * o(a[i], b[i], b[j]) <= 0 and \
                    o(a[j], b[j], a[i]) * o(a[j], b[j], b[i]) <= 0:
                out.add((i, j))
    return out


def test_self_intersections_match_the_quadratic_definition():
    rng = np.random.default_rng(0)
    for _ in range(25):
        iface = Interface.polyline(rng.normal(size=(int(rng.integers(3, 40)), 2)))
        assert set(segment_intersections(iface, max_report=10**9)) == _brute_intersections(iface)


def test_a_curve_with_millions_of_points_is_checked_without_pairwise_work():
    """A 2,000,000-point scan of a smooth interface: the sweep examines only nearby
    segments (seconds, not hours); a curve folded onto itself thousands of times is
    refused with the count and the limit instead."""
    x = np.linspace(0.0, 1.0, 2_000_000)
    assert segment_intersections(Interface.polyline(np.column_stack([x, 0.1 * np.sin(20 * x)]))) == []
    n = 20_000
    zigzag = np.column_stack([np.arange(n) % 2, np.linspace(0.0, 0.5, n)])
    with pytest.raises(InterfaceError, match="segment pairs"):
        segment_intersections(Interface.polyline(zigzag))

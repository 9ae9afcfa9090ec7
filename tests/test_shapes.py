"""Analytic colony shapes (bayescalib.geometry.shapes): the area and interface length
of a colony above the floor must match the closed forms for discs and ellipses to
1e-12 relative, a sampled outline must converge to them at second order, and a lobed
colony must be reproducible from its seed, of the requested size and fit for meshing."""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.geometry.outline import curve_length, signed_area
from bayescalib.geometry.shapes import (
    Colony,
    ShapeError,
    ellipse_patch,
    ellipse_segment_arc_length,
    ellipse_segment_area,
    lobed_colony,
)

#: (semi_x, semi_y, y_centre), mm: half-discs and -ellipses, cut below and above the centre
ELLIPSES = [(0.3, 0.3, 0.0), (0.3, 0.3, -0.1), (0.3, 0.4, 0.1), (0.4, 0.3, -0.1), (0.5, 0.2, 0.05)]


@pytest.mark.parametrize("a,b,yc", ELLIPSES)
def test_ellipse_area_and_perimeter_match_the_closed_forms(a, b, yc):
    """Quadrature over the arc against a b (acos h - h sqrt(1 - h^2)) and the incomplete
    elliptic integral: 1e-12 relative."""
    e = ellipse_patch(1.0, a, b, yc)
    assert e.area == pytest.approx(ellipse_segment_area(a, b, yc), rel=1e-12)
    assert e.perimeter == pytest.approx(ellipse_segment_arc_length(a, b, yc), rel=1e-12)


def test_disc_closed_forms_are_the_textbook_ones():
    """A half-disc: pi R^2 / 2 and pi R; a disc cut at its centre's height minus R/2
    (h = 1/2): R^2 (2 pi/3 + sqrt(3)/4) and 4 pi R / 3."""
    R = 0.3
    assert ellipse_segment_area(R, R, 0.0) == pytest.approx(0.5 * np.pi * R**2, rel=1e-14)
    assert ellipse_segment_arc_length(R, R, 0.0) == pytest.approx(np.pi * R, rel=1e-14)
    d = ellipse_patch(1.0, R, R, 0.5 * R)
    assert d.area == pytest.approx(R**2 * (2 * np.pi / 3 + np.sqrt(3) / 4), rel=1e-12)
    assert d.perimeter == pytest.approx(4 * np.pi * R / 3, rel=1e-12)
    assert d.base_width == pytest.approx(np.sqrt(3) * R, rel=1e-12)
    assert d.height == pytest.approx(1.5 * R, rel=1e-12)
    assert d.foot_angles() == pytest.approx((120.0, 120.0), abs=1e-9)  # an overhang


def test_outline_is_counterclockwise_with_its_feet_on_the_floor():
    c = lobed_colony(seed=0)
    o = c.outline(150)
    assert o.shape == (150, 2)
    assert signed_area(o) > 0
    assert o[0, 1] == 0.0 and o[-1, 1] == 0.0 and o[0, 0] > o[-1, 0]  # downstream foot first
    assert np.all(o[1:-1, 1] > 0)
    assert not np.allclose(o[0], o[-1])
    np.testing.assert_allclose(c.interface(150), o[::-1])  # the model's order: upstream first


@pytest.mark.parametrize("colony", [ellipse_patch(1.0, 0.4, 0.3, -0.1), lobed_colony(seed=0),
                                    lobed_colony(seed=2, width=0.7, height=0.3)],
                         ids=["ellipse", "lobed-0", "lobed-2"])
def test_polygon_converges_to_the_exact_area_and_perimeter_at_second_order(colony):
    """Doubling the points divides the polygon's area and length errors by about 4
    (observed order between 1.8 and 2.2); at 400 points both are below 1e-4 relative."""
    errs = []
    for n in (50, 100, 200, 400):
        o = colony.outline(n)
        errs.append((abs(signed_area(o) - colony.area) / colony.area,
                     abs(curve_length(o) - colony.perimeter) / colony.perimeter))
    errs = np.array(errs)
    order = np.log2(errs[:-1] / errs[1:])
    assert np.all((order > 1.8) & (order < 2.2)), order
    assert np.all(errs[-1] < 1e-4), errs[-1]


def test_quadrature_is_converged():
    """The lobed colony's area and perimeter do not move (1e-13) with twice the nodes."""
    c = lobed_colony(seed=0)
    t0, t1 = c.t_span
    x, w = np.polynomial.legendre.leggauss(1536)
    t, w = 0.5 * (t1 - t0) * x + 0.5 * (t1 + t0), 0.5 * (t1 - t0) * w
    p, d = c.point(t), c.derivative(t)
    area = 0.5 * np.sum(w * (p[:, 0] * d[:, 1] - p[:, 1] * d[:, 0]))
    assert c.area == pytest.approx(area, rel=1e-13)
    assert c.perimeter == pytest.approx(np.sum(w * np.hypot(d[:, 0], d[:, 1])), rel=1e-13)


def test_lobed_colony_is_reproducible_sized_and_fit_for_meshing():
    """Same seed, same colony; the requested width, height and centre to 1e-9 mm;
    inside x in [0.5, 1.5] mm; no neck below 0.15 mm, no bend below 0.04 mm radius, foot
    angles in [35, 130] degrees; other seeds give other colonies."""
    a, b = lobed_colony(seed=5), lobed_colony(seed=5)
    np.testing.assert_array_equal(a.outline(100), b.outline(100))
    assert lobed_colony(seed=6).modes != a.modes
    for seed, (w, h, xc) in enumerate([(0.8, 0.38, 1.0), (0.7, 0.3, 0.95), (0.9, 0.44, 1.0)]):
        c = lobed_colony(width=w, height=h, centre=xc, seed=seed)
        assert c.width == pytest.approx(w, abs=1e-9)
        assert c.height == pytest.approx(h, abs=1e-9)
        assert 0.5 * (c.bounds[0, 0] + c.bounds[1, 0]) == pytest.approx(xc, abs=1e-9)
        assert 0.5 <= c.bounds[0, 0] and c.bounds[1, 0] <= 1.5
        assert c.defects() == []
        assert c.neck() >= 0.15


def test_the_default_colony_is_irregular():
    """Seed 0 (the example's colony) overhangs downstream (foot angle > 110 degrees) and
    is not symmetric: its top is off the centre of its extent by more than 0.05 mm."""
    c = lobed_colony(seed=0)
    assert max(c.foot_angles()) > 110.0
    t0, t1 = c.t_span
    t = np.linspace(t0, t1, 4001)
    top = c.point(t)[np.argmax(c.point(t)[:, 1]), 0]
    assert abs(top - 1.0) > 0.05


def test_thin_necks_and_bad_cuts_are_reported():
    """A dumbbell (strong k = 2 mode across x) reports its neck; a curve entirely above
    the floor, or cut more than twice, is refused."""
    peanut = Colony(1.0, -0.05, 0.45, 0.25, ((2, 0.45, 0.0),), "peanut")
    assert any("neck" in d for d in peanut.defects())
    with pytest.raises(ShapeError, match="exactly twice"):
        _ = Colony(1.0, 0.5, 0.3, 0.3).t_span
    with pytest.raises(ShapeError, match="exactly twice"):
        _ = Colony(1.0, 0.05, 0.3, 0.3, ((4, -0.9, 0.0),)).t_span  # a W-shaped bottom
    with pytest.raises(ShapeError, match="no fit colony"):
        lobed_colony(seed=0, min_neck=10.0, max_tries=3)

"""Analytic biofilm colony shapes on the floor of a flow cell.

A colony is the part above the floor ``y = 0`` (mm) of a smooth closed radial curve

``x(t) = x0 + ax r(t) cos t``,  ``y(t) = y0 + ay r(t) sin t``,
``r(t) = 1 + sum_k eps_k cos(k t + phase_k)``,  ``t in [0, 2 pi)``,

which for ``r = 1`` is an ellipse with semi-axes ``ax``, ``ay`` centred at ``(x0, y0)``
(a disc for ``ax = ay``) and with a few Fourier modes ("lobes") an irregular, possibly
asymmetric or overhanging colony. The curve must cross the floor exactly twice; the
arc above it runs counterclockwise (increasing ``t``) from the downstream foot (larger
x) over the top to the upstream foot, and the floor closes it.

Area and perimeter
------------------
Both are integrals over the arc ``[t0, t1]`` between the two floor crossings (found
to machine precision by root bracketing) of trigonometric polynomials times smooth
functions, evaluated by Gauss-Legendre quadrature (:data:`QUADRATURE_NODES` nodes),
which converges exponentially for such integrands:

* area ``A = 1/2 int (x y' - y x') dt`` (Green's theorem; the floor adds nothing since
  ``y = 0`` and ``dy = 0`` there),
* perimeter ``P = int sqrt(x'^2 + y'^2) dt``: the fluid-biofilm interface only, the
  floor (the biofilm base) excluded.

For the ellipse they match the closed forms :func:`ellipse_segment_area` and
:func:`ellipse_segment_arc_length` (an incomplete elliptic integral of the second
kind) to ~1e-14 relative. A polygon sampled from the curve (:meth:`Colony.outline`)
converges to them at second order in the point spacing.

Lobed colonies
--------------
:func:`lobed_colony` draws the modes from a seeded generator and rescales the curve
to a given width (extent in x of the part above the floor) and height (largest y),
centred on a given x. Draws are rejected until the colony is well shaped for a finite
element model (:meth:`Colony.defects`): no thin neck (two points of the closed outline,
floor included, far apart along it but closer than ``min_neck`` in space), no sharp
bend (radius of curvature below ``min_radius``), foot angles in a range (the biofilm's
inner angle at the floor, between the floor and the interface tangent).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = [
    "QUADRATURE_NODES",
    "Colony",
    "ellipse_patch",
    "ellipse_segment_arc_length",
    "ellipse_segment_area",
    "lobed_colony",
]

#: Gauss-Legendre nodes of the area and perimeter integrals (converged to ~1e-14 for
#: curves with modes up to k = 8)
QUADRATURE_NODES = 768


class ShapeError(ValueError):
    """A colony that cannot be built (not cut twice by the floor, ill-shaped, ...)."""


@dataclass(frozen=True)
class Colony:
    """A colony on the floor: the part above ``y = 0`` of a radial curve.

    Attributes
    ----------
    x0, y0 : float
        Centre of the radial curve, mm (``y0 < 0``: centre below the floor).
    ax, ay : float
        Scale in x and y, mm (> 0); the semi-axes for ``r = 1``.
    modes : tuple of (int, float, float)
        ``(k, eps_k, phase_k)``: mode number (>= 1), relative amplitude, phase (rad).
    name : str
        Label (e.g. ``"lobed colony, seed 3"``).
    """

    x0: float
    y0: float
    ax: float
    ay: float
    modes: tuple[tuple[int, float, float], ...] = ()
    name: str = "colony"

    def __post_init__(self) -> None:
        if not (self.ax > 0 and self.ay > 0):
            raise ShapeError(f"{self.name}: scales ax, ay must be > 0 mm, got {self.ax}, {self.ay}")
        if sum(abs(e) for _, e, _ in self.modes) >= 1.0:
            raise ShapeError(f"{self.name}: sum |eps_k| must be < 1 (r > 0 everywhere)")

    # ---------------------------------------------------------------- the curve
    def radius(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``r(t)`` and ``r'(t)`` (dimensionless), shape of ``t``."""
        t = np.asarray(t, dtype=float)
        r = np.ones_like(t)
        dr = np.zeros_like(t)
        for k, eps, phase in self.modes:
            r = r + eps * np.cos(k * t + phase)
            dr = dr - eps * k * np.sin(k * t + phase)
        return r, dr

    def point(self, t: np.ndarray) -> np.ndarray:
        """Points of the curve, shape ``t.shape + (2,)``, mm."""
        r, _ = self.radius(t)
        return np.stack([self.x0 + self.ax * r * np.cos(t), self.y0 + self.ay * r * np.sin(t)], -1)

    def derivative(self, t: np.ndarray) -> np.ndarray:
        """``(x'(t), y'(t))``, shape ``t.shape + (2,)``, mm/rad."""
        r, dr = self.radius(t)
        c, s = np.cos(t), np.sin(t)
        return np.stack([self.ax * (dr * c - r * s), self.ay * (dr * s + r * c)], -1)

    def second_derivative(self, t: np.ndarray) -> np.ndarray:
        """``(x''(t), y''(t))``, shape ``t.shape + (2,)``, mm/rad^2."""
        t = np.asarray(t, dtype=float)
        r, dr = self.radius(t)
        ddr = np.zeros_like(t)
        for k, eps, phase in self.modes:
            ddr = ddr - eps * k * k * np.cos(k * t + phase)
        c, s = np.cos(t), np.sin(t)
        return np.stack([self.ax * (ddr * c - 2 * dr * s - r * c),
                         self.ay * (ddr * s + 2 * dr * c - r * s)], -1)

    # ---------------------------------------------------------------- the cut
    @cached_property
    def t_span(self) -> tuple[float, float]:
        """``(t0, t1)``, ``t0 < t1 < t0 + 2 pi``: the arc above the floor, rad.

        ``t0`` is where the curve rises through ``y = 0`` (the downstream foot for a
        colony leaning on nothing), ``t1`` where it comes down again.

        Raises
        ------
        ShapeError
            If the curve does not cross the floor exactly twice.
        """
        from scipy.optimize import brentq

        def y(t: float) -> float:
            return float(self.point(np.asarray(t))[1])

        t = np.linspace(0.0, 2.0 * np.pi, 4097)
        yy = self.point(t)[:, 1]
        sign = np.sign(yy[:-1]) * np.sign(yy[1:])
        idx = np.flatnonzero(sign <= 0)
        roots = []
        for i in idx:
            a, b = t[i], t[i + 1]
            if yy[i] == 0.0:
                root = a
            elif yy[i + 1] == 0.0:
                continue  # found as the left end of the next interval
            else:
                root = brentq(y, a, b, xtol=1e-15, rtol=1e-15)
            rising = float(self.derivative(np.asarray(root))[1]) > 0
            roots.append((root, rising))
        if len(roots) != 2:
            raise ShapeError(f"{self.name}: the curve must cross the floor y = 0 exactly twice, "
                             f"found {len(roots)} crossings")
        up = [r for r, rising in roots if rising]
        down = [r for r, rising in roots if not rising]
        if len(up) != 1 or len(down) != 1:
            raise ShapeError(f"{self.name}: the curve touches the floor without crossing it")
        t0, t1 = up[0], down[0]
        if t1 <= t0:
            t1 += 2.0 * np.pi
        return float(t0), float(t1)

    def _gauss(self, n: int = QUADRATURE_NODES) -> tuple[np.ndarray, np.ndarray]:
        t0, t1 = self.t_span
        x, w = np.polynomial.legendre.leggauss(n)
        return 0.5 * (t1 - t0) * x + 0.5 * (t1 + t0), 0.5 * (t1 - t0) * w

    @cached_property
    def area(self) -> float:
        """Area above the floor, mm^2 (Gauss-Legendre, see the module docstring)."""
        t, w = self._gauss()
        p, d = self.point(t), self.derivative(t)
        return float(0.5 * np.sum(w * (p[:, 0] * d[:, 1] - p[:, 1] * d[:, 0])))

    @cached_property
    def perimeter(self) -> float:
        """Length of the fluid-biofilm interface (the arc above the floor), mm."""
        t, w = self._gauss()
        d = self.derivative(t)
        return float(np.sum(w * np.hypot(d[:, 0], d[:, 1])))

    @cached_property
    def feet(self) -> np.ndarray:
        """(2, 2): the upstream (left) and downstream (right) foot on the floor, mm."""
        t0, t1 = self.t_span
        p = self.point(np.array([t1, t0]))
        p[:, 1] = 0.0
        return p

    def _extreme(self, k: int, sign: float) -> float:
        from scipy.optimize import minimize_scalar

        t0, t1 = self.t_span
        t = np.linspace(t0, t1, 4001)
        v = sign * self.point(t)[:, k]
        i = int(np.argmin(v))
        lo, hi = t[max(i - 1, 0)], t[min(i + 1, t.size - 1)]
        if hi - lo <= 0:
            return float(sign * v[i])
        res = minimize_scalar(lambda s: sign * float(self.point(np.asarray(s))[k]),
                              bounds=(lo, hi), method="bounded", options={"xatol": 1e-13})
        return float(sign * min(res.fun, v[i]))

    @cached_property
    def bounds(self) -> np.ndarray:
        """``[[xmin, 0], [xmax, ymax]]`` of the part above the floor, mm."""
        return np.array([[self._extreme(0, 1.0), 0.0],
                         [self._extreme(0, -1.0), self._extreme(1, -1.0)]])

    @property
    def width(self) -> float:
        """Extent in x of the part above the floor, mm."""
        b = self.bounds
        return float(b[1, 0] - b[0, 0])

    @property
    def height(self) -> float:
        """Largest y, mm."""
        return float(self.bounds[1, 1])

    @property
    def base_width(self) -> float:
        """Length of the biofilm base (between the feet), mm."""
        return float(self.feet[1, 0] - self.feet[0, 0])

    # ---------------------------------------------------------------- sampling
    def _arc_parameters(self, n: int) -> np.ndarray:
        """``n`` parameters from ``t0`` to ``t1``, equally spaced in arc length."""
        t0, t1 = self.t_span
        fine = np.linspace(t0, t1, max(64 * n, 20001))
        d = self.derivative(fine)
        speed = np.hypot(d[:, 0], d[:, 1])
        s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fine))])
        return np.interp(np.linspace(0.0, s[-1], n), s, fine)

    def outline(self, n: int = 200) -> np.ndarray:
        """Polygon of the colony above the floor, counterclockwise.

        Parameters
        ----------
        n : int
            Points on the arc (>= 3), equally spaced in arc length.

        Returns
        -------
        ndarray, shape (n, 2)
            mm; the first point is the downstream foot and the last the upstream
            foot, both with ``y = 0`` exactly; the polygon closes along the floor (the
            first point is not repeated). It is the ``outline`` of the fsi model's
            ``geometry.shape: polyline``.
        """
        if int(n) < 3:
            raise ValueError(f"outline needs n >= 3 points, got {n}")
        pts = self.point(self._arc_parameters(int(n)))
        pts[[0, -1], 1] = 0.0
        return pts

    def interface(self, n: int = 200) -> np.ndarray:
        """The fluid-biofilm interface as the fsi model orders it: from the upstream
        foot to the downstream foot (the biofilm on its right), shape (n, 2), mm."""
        return self.outline(n)[::-1].copy()

    # ---------------------------------------------------------------- checks
    def curvature_radius(self, t: np.ndarray) -> np.ndarray:
        """Signed radius of curvature at ``t``, mm (> 0 convex, < 0 concave)."""
        d, dd = self.derivative(t), self.second_derivative(t)
        cross = d[..., 0] * dd[..., 1] - d[..., 1] * dd[..., 0]
        speed = np.hypot(d[..., 0], d[..., 1])
        with np.errstate(divide="ignore"):
            return speed**3 / cross

    def foot_angles(self) -> tuple[float, float]:
        """Inner angles of the biofilm at the upstream and downstream foot, degrees
        (90: the interface leaves the floor vertically; > 90: an overhang)."""
        t0, t1 = self.t_span
        d = self.derivative(np.array([t1, t0]))
        # upstream foot (t1): the counterclockwise arc arrives going down, so the interface
        # leaves the floor along -x'(t1): the angle from +x (into the biofilm) to it;
        # downstream foot (t0): it leaves along +x'(t0), measured from -x
        up = np.degrees(np.arctan2(-d[0, 1], -d[0, 0]))
        down = np.degrees(np.arctan2(d[1, 1], -d[1, 0]))
        return float(up), float(down)

    def neck(self, exclude: float = 0.15, n: int = 400) -> float:
        """Narrowest neck of the closed outline (floor included), mm.

        The smallest distance between two points of the outline whose distance along
        it is at least ``pi/2`` times their distance in space (a disc of diameter d
        has its narrowest neck d, a dumbbell its waist, a tall thin stalk its width).
        Points closer than ``exclude`` (mm, along the outline) to a foot are left
        out: an acute foot is a corner, not a neck (:meth:`foot_angles` bounds it).
        """
        arc = self.outline(n)
        h = self.perimeter / (n - 1)
        floor = np.linspace(arc[-1], arc[0], max(int(np.ceil(self.base_width / h)), 1) + 1)[1:-1]
        pts = np.vstack([arc, floor])
        seg = np.hypot(*np.diff(np.vstack([pts, pts[:1]]), axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
        total = float(seg.sum())

        def periodic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            d = np.abs(a - b)
            return np.minimum(d, total - d)

        feet = np.array([s[0], s[n - 1]])  # downstream foot, upstream foot
        keep = periodic(s[:, None], feet[None, :]).min(axis=1) >= exclude
        pts, s = pts[keep], s[keep]
        if pts.shape[0] < 2:
            return float("inf")
        along = periodic(s[:, None], s[None, :])
        dist = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
        far = along >= 0.5 * np.pi * dist + 1e-12
        np.fill_diagonal(far, False)
        return float(dist[far].min()) if far.any() else float("inf")

    def defects(self, *, min_neck: float = 0.15, min_radius: float = 0.04,
                foot_angle: tuple[float, float] = (35.0, 130.0)) -> list[str]:
        """What makes the colony unfit for a finite element model (empty: fit).

        Parameters
        ----------
        min_neck : float
            Smallest allowed neck (:meth:`neck`), mm.
        min_radius : float
            Smallest allowed radius of curvature of the interface, mm.
        foot_angle : (float, float)
            Allowed range of the biofilm's inner angles at the feet, degrees.
        """
        out = []
        neck = self.neck(exclude=min_neck)
        if neck < min_neck:
            out.append(f"neck {neck:.3f} mm < {min_neck} mm")
        if self.base_width < min_neck:
            out.append(f"base {self.base_width:.3f} mm wide < {min_neck} mm")
        t0, t1 = self.t_span
        rc = np.abs(self.curvature_radius(np.linspace(t0, t1, 2001)))
        if rc.min() < min_radius:
            out.append(f"radius of curvature {rc.min():.3f} mm < {min_radius} mm")
        for where, a in zip(("upstream", "downstream"), self.foot_angles()):
            if not foot_angle[0] <= a <= foot_angle[1]:
                out.append(f"{where} foot angle {a:.0f} deg outside {foot_angle}")
        return out

    def fsi_geometry(self, n: int = 200) -> dict:
        """The fsi model's ``geometry`` keys of this colony (``shape: polyline``)."""
        return {"shape": "polyline", "outline": self.outline(n).tolist()}


# -------------------------------------------------------------------- constructors
def ellipse_patch(centre: float, semi_x: float, semi_y: float, y_centre: float = 0.0) -> Colony:
    """The part above the floor of an ellipse (a disc for ``semi_x == semi_y``).

    Parameters
    ----------
    centre : float
        x of the centre, mm.
    semi_x, semi_y : float
        Semi-axes, mm.
    y_centre : float
        y of the centre, mm, ``|y_centre| < semi_y`` (0: a half-ellipse, the fsi
        model's ``half_ellipse`` shape; > 0: an overhang).
    """
    if not abs(y_centre) < semi_y:
        raise ShapeError(f"ellipse: |y_centre| = {abs(y_centre)} mm must be < semi_y = {semi_y} mm")
    return Colony(float(centre), float(y_centre), float(semi_x), float(semi_y), (), "ellipse")


def lobed_colony(
    *,
    width: float = 0.8,
    height: float = 0.38,
    centre: float = 1.0,
    lobes: int = 4,
    amplitude: float = 0.22,
    depth: tuple[float, float] = (-0.25, 0.15),
    seed: int = 0,
    min_neck: float = 0.15,
    min_radius: float = 0.04,
    foot_angle: tuple[float, float] = (35.0, 130.0),
    max_tries: int = 500,
) -> Colony:
    """An irregular colony: random modes, rescaled to a width and height.

    Draws ``r(t) = 1 + sum_{k=2}^{lobes+1} eps_k cos(k t + phase_k)`` with
    ``eps_k = amplitude * u_k / k^0.5`` (``u_k`` uniform in [-1, 1], so the higher
    modes are smaller), uniform phases, and the height of the floor below the centre
    ``-y0`` uniform in ``depth`` (in units of the unit curve; a negative value cuts
    the curve above its centre: an overhang is likely). The curve is then scaled
    in x and y so that the part above the floor is ``width`` wide (mm) and
    ``height`` high (mm) and shifted so that its x-extent is centred on ``centre``.
    A draw is rejected until :meth:`Colony.defects` is empty.

    Parameters
    ----------
    width, height, centre : float
        mm.
    lobes : int
        Number of Fourier modes (k = 2 .. lobes + 1).
    amplitude : float
        Scale of the mode amplitudes (sum of ``|eps_k|`` < 1 is enforced).
    depth : (float, float)
        Range of the floor's depth below the centre of the unit curve.
    seed : int
        Seed of the :class:`numpy.random.Generator` (same seed, same colony).
    min_neck, min_radius, foot_angle
        As in :meth:`Colony.defects` (mm, mm, degrees).
    max_tries : int
        Draws before giving up.

    Returns
    -------
    Colony

    Raises
    ------
    ShapeError
        If no fit colony was drawn in ``max_tries`` draws.
    """
    rng = np.random.default_rng(seed)
    last = ""
    for _ in range(int(max_tries)):
        ks = np.arange(2, int(lobes) + 2)
        eps = amplitude * rng.uniform(-1.0, 1.0, ks.size) / np.sqrt(ks)
        phases = rng.uniform(0.0, 2.0 * np.pi, ks.size)
        y0 = -float(rng.uniform(*depth))
        if np.sum(np.abs(eps)) >= 0.9:
            last = "mode amplitudes too large"
            continue
        modes = tuple((int(k), float(e), float(p)) for k, e, p in zip(ks, eps, phases))
        name = f"lobed colony (seed {seed})"
        try:
            unit = Colony(0.0, y0, 1.0, 1.0, modes, name)
            b = unit.bounds
            sx = width / (b[1, 0] - b[0, 0])
            sy = height / b[1, 1]
            xmid = 0.5 * (b[0, 0] + b[1, 0])
            colony = Colony(centre - sx * xmid, sy * y0, sx, sy, modes, name)
            problems = colony.defects(min_neck=min_neck, min_radius=min_radius,
                                      foot_angle=foot_angle)
        except ShapeError as exc:
            last = str(exc)
            continue
        if not problems:
            return colony
        last = "; ".join(problems)
    raise ShapeError(f"lobed_colony: no fit colony in {max_tries} draws (seed {seed}); "
                     f"last: {last}")


# -------------------------------------------------------------------- closed forms
def ellipse_segment_area(semi_x: float, semi_y: float, y_centre: float) -> float:
    """Area of the ellipse above ``y = 0`` (centre at height ``y_centre``), mm^2:
    ``a b (acos(h) - h sqrt(1 - h^2))`` with ``h = -y_centre / b`` (a circular
    segment stretched by ``a`` and ``b``)."""
    h = -float(y_centre) / float(semi_y)
    return float(semi_x * semi_y * (np.arccos(h) - h * np.sqrt(1.0 - h * h)))


def ellipse_segment_arc_length(semi_x: float, semi_y: float, y_centre: float) -> float:
    """Length of the elliptic arc above ``y = 0``, mm.

    With ``x = a cos t``, ``y = y_c + b sin t`` the arc is ``t in [t0, pi - t0]``,
    ``sin t0 = -y_c / b``, and its length ``int sqrt(a^2 sin^2 t + b^2 cos^2 t) dt``
    ``= 2 a E(pi/2 - t0 | 1 - b^2/a^2)`` for ``a >= b`` and
    ``= b (E(pi - t0 | m) - E(t0 | m))``, ``m = 1 - a^2/b^2`` otherwise, with ``E(phi | m)``
    the incomplete elliptic integral of the second kind (:func:`scipy.special.ellipeinc`).
    """
    from scipy.special import ellipeinc

    a, b = float(semi_x), float(semi_y)
    t0 = float(np.arcsin(-float(y_centre) / b))
    if a >= b:
        return float(2.0 * a * ellipeinc(0.5 * np.pi - t0, 1.0 - b * b / (a * a)))
    m = 1.0 - a * a / (b * b)
    return float(b * (ellipeinc(np.pi - t0, m) - ellipeinc(t0, m)))

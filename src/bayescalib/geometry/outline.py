"""The model's undeformed biofilm from a recording: colony outlines.

The field's practice (Picioreanu et al. 2018) takes the undeformed biofilm
geometry from the scan at zero (or the lowest) flow, meshes that shape and fits
the scans at higher flows. This module holds the pure steps from a traced curve
(mm) to an outline the mesh generator can take; reading files is
:mod:`bayescalib.io.colony`'s job.

Steps
-----
1. **Colony choice** (:func:`select_colony`): the mask's connected foreground
   components (8-connectivity) are the colonies; the one the user names by an
   x-range, else the largest, is kept, and the choice is reported. A colony that
   touches the left, right or top image border is cut by the field of view and
   refused: the model would mesh a shape that is not the biofilm's.
2. **The interface** (:func:`interface_above_floor`): the part of the traced
   boundary above the substrate, an open curve ordered from the upstream foot
   (smaller x) to the downstream foot, so that its left-hand normals point into
   the fluid (:mod:`bayescalib.geometry.interface`).
3. **Smoothing at a stated length** (:func:`smooth_curve`): a Gaussian filter of
   standard deviation ``length`` along arc length. A contour traced by marching
   squares follows the pixel staircase (amplitude up to half a pixel at 45
   degrees); left in, every step would become mesh detail. For a curve of radius
   of curvature ``R`` the filter moves the curve inwards by about
   ``length**2 / (2 R)`` (a circle of 60 pixels smoothed at 2 pixels: 0.03
   pixel), far below the segmentation's own error. The feet stay in place
   (odd reflection about each end point).
4. **Resampling** (:func:`resample_curve`) to uniform arc-length spacing, so the
   spline the mesh generator fits through the points has no clustered nodes.
5. **Checks** (:func:`validate_colony`): a simple curve inside the channel, no
   self-touching (two parts of the interface, or the interface and the floor,
   closer than ``min_gap`` where the curve between them is much longer): a
   gap narrower than about two elements cannot be meshed with the interface
   resolution asked for, and netgen either fails or hangs on it.

The orientation of a closed outline (:func:`counterclockwise`) is normalized
before meshing: OpenCascade builds no triangulation of a face whose wire runs
clockwise (``OCC-Triangulation could not be built``), and a tracer returns
either order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ColonyChoice",
    "OutlineError",
    "Placement",
    "counterclockwise",
    "curve_length",
    "extend_to_floor",
    "interface_above_floor",
    "placement",
    "polygon_area",
    "resample_curve",
    "select_colony",
    "signed_area",
    "smooth_curve",
    "validate_colony",
]


class OutlineError(ValueError):
    """An outline that cannot be the model's biofilm; the message says why."""


# ------------------------------------------------------------------ polygons
def signed_area(points: np.ndarray) -> float:
    """Signed area of a closed polygon (shoelace; positive when counterclockwise).

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Vertices in order, the first not repeated at the end (a repeated one adds
        nothing).
    """
    p = np.asarray(points, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_area(points: np.ndarray) -> float:
    """Area of a simple closed polygon, mm^2 (:func:`signed_area` without sign)."""
    return abs(signed_area(points))


def curve_length(points: np.ndarray) -> float:
    """Length of an open polyline, mm. ``points``: (n, 2), in order."""
    p = np.asarray(points, dtype=float)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def counterclockwise(points: np.ndarray) -> np.ndarray:
    """The vertices of a closed polygon in counterclockwise order.

    A repeated last point is dropped; a clockwise polygon is reversed. The set of
    vertices and the polygon are unchanged.

    Parameters
    ----------
    points : array_like, shape (n, 2)

    Returns
    -------
    ndarray, shape (m, 2)
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise OutlineError(f"an outline needs at least 3 points [x, y], got shape {p.shape}")
    if np.allclose(p[0], p[-1]):
        p = p[:-1]
    return p[::-1].copy() if signed_area(p) < 0 else p.copy()


# -------------------------------------------------------------------- curves
def _arc(points: np.ndarray, closed: bool) -> np.ndarray:
    p = np.vstack([points, points[:1]]) if closed else points
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]


def resample_curve(points: np.ndarray, spacing: float, *, closed: bool = False) -> np.ndarray:
    """Points at uniform arc-length spacing along a polyline (linear interpolation).

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Ordered curve, mm.
    spacing : float
        Target spacing, mm (> 0); the actual one is the curve length divided by
        the nearest whole number of intervals.
    closed : bool
        The curve closes from its last point back to its first (which is then not
        repeated in the result).

    Returns
    -------
    ndarray, shape (m, 2)
        An open curve keeps both end points.
    """
    p = np.asarray(points, dtype=float)
    if not (np.isfinite(spacing) and spacing > 0):
        raise OutlineError(f"resampling spacing must be > 0 mm, got {spacing}")
    s = _arc(p, closed)
    total = float(s[-1])
    if total <= 0:
        raise OutlineError("the curve has zero length")
    n = max(round(total / spacing), 3 if closed else 1)
    q = np.linspace(0.0, total, n + 1)
    if closed:
        q = q[:-1]
    src = np.vstack([p, p[:1]]) if closed else p
    keep = np.r_[True, np.diff(s) > 0]  # repeated points would break the interpolation
    return np.column_stack([np.interp(q, s[keep], src[keep, 0]), np.interp(q, s[keep], src[keep, 1])])


def smooth_curve(points: np.ndarray, length: float, *, closed: bool = False) -> np.ndarray:
    """Gaussian smoothing of a curve along its arc length.

    The curve is resampled at a spacing of ``length / 4`` (or finer, as the input
    is) and each coordinate filtered with a Gaussian of standard deviation
    ``length`` in arc length. An open curve is extended by odd reflection about
    each end point, which keeps the end points where they are (the feet of a
    colony stay on the floor) and a straight end straight.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Ordered curve, mm.
    length : float
        Standard deviation of the filter, mm (0: the curve is returned as it is).
    closed : bool
        Periodic filtering of a closed curve.

    Returns
    -------
    ndarray, shape (m, 2)
        The smoothed curve at the working spacing (resample it for the mesh).
    """
    from scipy.ndimage import gaussian_filter1d

    p = np.asarray(points, dtype=float)
    if not (np.isfinite(length) and length >= 0):
        raise OutlineError(f"smoothing length must be >= 0 mm, got {length}")
    if length == 0:
        return p.copy()
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    h = min(length / 4.0, float(np.median(seg[seg > 0])) if np.any(seg > 0) else length / 4.0)
    q = resample_curve(p, h, closed=closed)
    sd = length / h  # in samples
    if closed:
        return gaussian_filter1d(q, sd, axis=0, mode="wrap")
    pad = min(int(np.ceil(4 * sd)), q.shape[0] - 1)
    left = 2 * q[0] - q[pad:0:-1]
    right = 2 * q[-1] - q[-2 : -pad - 2 : -1]
    ext = np.vstack([left, q, right])
    out = gaussian_filter1d(ext, sd, axis=0, mode="nearest")[pad : pad + q.shape[0]]
    out[0], out[-1] = q[0], q[-1]
    return out


def interface_above_floor(points: np.ndarray, *, floor: float = 0.0, closed: bool,
                          tol: float = 0.0) -> np.ndarray:
    """The fluid–biofilm interface of an outline: its part above the floor.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        A closed outline of the colony (either orientation) or an open interface
        curve (either direction), mm.
    floor : float
        y of the substrate, mm.
    closed : bool
        Whether ``points`` is a closed outline; its longest run of points above
        ``floor + tol`` is the interface.
    tol : float
        Points within ``tol`` above the floor count as on it (mm; e.g. half a
        pixel for a traced mask).

    Returns
    -------
    ndarray, shape (m, 2)
        Open curve from the upstream foot (the end with the smaller x) to the
        downstream foot: over a colony this is clockwise, so the left-hand
        normals point into the fluid.
    """
    p = np.asarray(points, dtype=float)
    if closed:
        if np.allclose(p[0], p[-1]):
            p = p[:-1]
        keep = p[:, 1] > floor + tol
        if not keep.any():
            raise OutlineError(f"the whole outline lies on or below the floor y = {floor:g} mm")
        if keep.all():
            raise OutlineError(
                f"the outline does not reach the floor y = {floor:g} mm (its lowest point is at "
                f"y = {p[:, 1].min():.4g} mm): a biofilm colony sits on the substrate")
        shift = int(np.flatnonzero(~keep)[0]) + 1
        p, keep = np.roll(p, -shift, axis=0), np.roll(keep, -shift)
        edges = np.diff(np.r_[0, keep.astype(int), 0])
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        k = int(np.argmax(ends - starts))
        n = p.shape[0]
        run = p[starts[k] : ends[k]]
        if run.shape[0] < 3:
            raise OutlineError("fewer than 3 outline points lie above the floor")
        # the feet: where the outline crosses y = floor + tol into and out of the run
        y_c = floor + tol
        feet = []
        for a, b in ((p[(starts[k] - 1) % n], run[0]), (run[-1], p[ends[k] % n])):
            w = (y_c - a[1]) / (b[1] - a[1]) if b[1] != a[1] else 0.0
            feet.append(a + w * (b - a))
        p = np.vstack([feet[0], run, feet[1]])
    if p[0, 0] > p[-1, 0]:
        p = p[::-1]
    return p.copy()


def extend_to_floor(interface: np.ndarray, floor: float, *, reach: float) -> np.ndarray:
    """Continue both ends of an interface down to the floor.

    A traced interface stops just above the substrate (a mask's boundary pixels on
    the floor are not interface); its feet are where it meets the floor. Each end
    is continued along its own direction (the chord over the last ``reach`` of arc
    length) to ``y = floor``, at most ``reach`` sideways; an end already on or
    below the floor is kept.

    Parameters
    ----------
    interface : array_like, shape (n, 2)
        Open curve from foot to foot, mm.
    floor : float
        y of the substrate, mm.
    reach : float
        Length scale of the ends (e.g. two pixels), mm.

    Returns
    -------
    ndarray, shape (m, 2)
        With a new first and last point on the floor where they were above it.
    """
    p = np.asarray(interface, dtype=float)
    s = _arc(p, closed=False)
    out = [p]
    for end, sign in ((0, 1), (-1, -1)):
        q = p[end]
        if q[1] <= floor:
            continue
        k = int(np.searchsorted(s, reach)) if end == 0 else \
            int(np.searchsorted(s, s[-1] - reach)) - 1
        k = min(max(k, 1), p.shape[0] - 2)
        d = q - p[k]
        if d[1] < -1e-12:  # heading down to the floor: continue along it
            t = (q[1] - floor) / -d[1]
            dx = float(np.clip(t * d[0], -reach, reach))
        else:
            dx = 0.0
        foot = np.array([[q[0] + dx, floor]])
        out = [foot, *out] if end == 0 else [*out, foot]
    return np.vstack(out)


# -------------------------------------------------------------------- colonies
@dataclass
class ColonyChoice:
    """Which connected component of a mask is the modelled colony, and why.

    Attributes
    ----------
    index : int
        0-based rank of the chosen component by area (0 = largest).
    n_colonies : int
        Components of at least ``min_pixels`` pixels.
    x_ranges : list of (float, float)
        Column range (first, last) of every such component, by area.
    areas : list of int
        Their pixel counts.
    by : str
        ``"largest"`` or ``"x_range"``.
    words : str
        One sentence for the user.
    """

    index: int
    n_colonies: int
    x_ranges: list[tuple[int, int]] = field(default_factory=list)
    areas: list[int] = field(default_factory=list)
    by: str = "largest"
    words: str = ""


def select_colony(mask: np.ndarray, *, columns: tuple[float, float] | None = None,
                  min_pixels: int = 16, name: str = "scan",
                  refuse_cut: bool = True) -> tuple[np.ndarray, ColonyChoice]:
    """The colony to model among the mask's connected components.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
        Biofilm True, row 0 the top, the substrate already removed (the colonies
        must not be joined through it).
    columns : (float, float), optional
        A column range (may be fractional): the component with the most pixels in
        it is chosen. None: the largest component.
    min_pixels : int
        Components smaller than this are specks, not colonies.
    name : str
        Used in messages.
    refuse_cut : bool
        Refuse a chosen colony that touches the left, right or top image border (the
        model's colony); False for an observed one (whose reader says where it is cut).

    Returns
    -------
    component : ndarray of bool, shape (H, W)
    choice : ColonyChoice

    Raises
    ------
    OutlineError
        No colony, none in the range, or (``refuse_cut``) the chosen one touches the
        left, right or top image border (cut by the field of view).
    """
    from scipy.ndimage import label

    m = np.asarray(mask, dtype=bool)
    lab, n = label(m, structure=np.ones((3, 3), dtype=int))
    sizes = np.bincount(lab.ravel())[1:] if n else np.zeros(0, dtype=int)
    ids = [int(i) + 1 for i in np.argsort(-sizes, kind="stable") if sizes[i] >= min_pixels]
    if not ids:
        raise OutlineError(f"{name}: no colony found (no foreground region of at least "
                           f"{min_pixels} pixels)")
    ranges, areas = [], []
    for i in ids:
        cols = np.flatnonzero((lab == i).any(axis=0))
        ranges.append((int(cols[0]), int(cols[-1])))
        areas.append(int(sizes[i - 1]))
    if columns is None:
        k, by = 0, "largest"
    else:
        lo, hi = sorted(float(c) for c in columns)
        c0, c1 = int(np.ceil(max(lo, 0))), int(np.floor(min(hi, m.shape[1] - 1)))
        inside = [int(np.count_nonzero(lab[:, c0 : c1 + 1] == i)) if c1 >= c0 else 0 for i in ids]
        if max(inside) == 0:
            raise OutlineError(f"{name}: no colony lies in the given x-range "
                               f"(columns {lo:.1f} to {hi:.1f})")
        k, by = int(np.argmax(inside)), "x_range"
    comp = lab == ids[k]
    rows, cols = np.flatnonzero(comp.any(axis=1)), np.flatnonzero(comp.any(axis=0))
    cut = [side for side, hit in (("left", cols[0] == 0), ("right", cols[-1] == m.shape[1] - 1),
                                  ("top", rows[0] == 0)) if hit]
    if cut and refuse_cut:
        raise OutlineError(
            f"{name}: the colony touches the image's {' and '.join(cut)} border: it is cut by "
            "the field of view, and the model would mesh a shape that is not the biofilm's. "
            "Use a scan that shows the whole colony")
    words = (f"{len(ids)} colonies in the scan; modelled: the "
             + ("largest" if by == "largest" else "one in the given x-range")
             + f", columns {ranges[k][0]}-{ranges[k][1]}, {areas[k]} pixels") if len(ids) > 1 \
        else f"one colony in the scan, columns {ranges[0][0]}-{ranges[0][1]}, {areas[0]} pixels"
    return comp, ColonyChoice(k, len(ids), ranges, areas, by, words)


def validate_colony(interface: np.ndarray, *, channel_length: float, channel_height: float,
                 min_gap: float, name: str = "outline") -> None:
    """Refuse an interface the model cannot mesh or should not take.

    Parameters
    ----------
    interface : array_like, shape (n, 2)
        Open curve above the floor y = 0 from foot to foot, mm (as
        :func:`interface_above_floor` returns it, resampled).
    channel_length, channel_height : float
        The flow cell, mm: the colony must lie inside, clear of the inlet, the
        outlet and the top.
    min_gap : float
        Narrowest gap the mesh can resolve, mm (about two interface elements).
    name : str
        Used in messages (the config key or file).

    Raises
    ------
    OutlineError
        Naming the problem and where it is.
    """
    from scipy.spatial import cKDTree

    from bayescalib.geometry.interface import Interface, segment_intersections

    p = np.asarray(interface, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise OutlineError(f"{name}: the interface needs at least 3 points, got shape {p.shape}")
    lo, hi = p.min(axis=0), p.max(axis=0)
    if lo[0] <= 0 or hi[0] >= channel_length:
        raise OutlineError(
            f"{name}: the colony spans x = {lo[0]:.4g} to {hi[0]:.4g} mm, outside the channel "
            f"(0 to {channel_length:g} mm): check the scan's origin and units")
    if hi[1] >= channel_height:
        raise OutlineError(f"{name}: the colony is {hi[1]:.4g} mm high, not below the channel "
                           f"top ({channel_height:g} mm): check the scan's pixel size and units")
    if lo[1] < -min_gap:
        raise OutlineError(f"{name}: the interface reaches y = {lo[1]:.4g} mm, below the floor "
                           "(y = 0): check the scan's origin")
    curve = Interface.polyline(p, name=name)
    hits = segment_intersections(curve, max_report=1)
    if hits:
        i, _ = hits[0]
        raise OutlineError(f"{name}: the outline crosses itself near "
                           f"({p[i, 0]:.4g}, {p[i, 1]:.4g}) mm")
    s = _arc(p, closed=False)
    tree = cKDTree(p)
    for i, j in sorted(tree.query_pairs(min_gap)):
        if abs(s[j] - s[i]) > 3.0 * min_gap + 1e-12:
            gap = float(np.linalg.norm(p[i] - p[j]))
            raise OutlineError(
                f"{name}: the outline nearly touches itself between ({p[i, 0]:.4g}, "
                f"{p[i, 1]:.4g}) and ({p[j, 0]:.4g}, {p[j, 1]:.4g}) mm: a gap of {gap:.3g} mm, "
                f"narrower than {min_gap:.3g} mm (two interface elements); the mesh cannot "
                "resolve it. Smooth the outline more, pick a finer mesh, or fill the gap")
    # a fluid gap under an overhang: a point low above the floor, away from the feet,
    # with the fluid below it (its left-hand normal, into the fluid, points down)
    t = np.gradient(p, axis=0)
    ny = t[:, 0] / np.maximum(np.linalg.norm(t, axis=1), 1e-300)
    far = (s > 3.0 * min_gap) & (s[-1] - s > 3.0 * min_gap)
    low = far & (p[:, 1] < min_gap) & (ny < -0.3)
    if low.any():
        i = int(np.flatnonzero(low)[0])
        raise OutlineError(
            f"{name}: an overhang of the outline comes within {p[i, 1]:.3g} mm of the floor at "
            f"x = {p[i, 0]:.4g} mm: the fluid gap under it is narrower than {min_gap:.3g} mm "
            "(two interface elements), which the mesh cannot resolve")


# ------------------------------------------------------------------- placement
@dataclass
class Placement:
    """Where an observed interface lies relative to the model's undeformed one.

    Attributes
    ----------
    mean_distance : float
        Mean distance of the observed nodes from the model's undeformed interface, mm.
    extent_ratio : float
        Observed x-extent over the model's (1 when the units agree).
    offset : (float, float) or (float, float, float)
        Estimated misplacement (dx, dy), mm: the mean x-shift of the two feet and
        the shift of the lowest point; for a surface (dx, dy, dz): the shift of the
        footprint's centre and of the top
        (:func:`bayescalib.geometry.surface.surface_placement`).
    """

    mean_distance: float
    extent_ratio: float
    offset: tuple[float, ...]


def downstream_shift(observed: np.ndarray, reference: np.ndarray) -> float:
    """How far an observed 2D interface has moved downstream (+x, the flow) of the
    model's undeformed one, mm: the mean x of each observed node's offset from its
    closest point on the reference, weighted by the node's height (the top moves most,
    the feet not at all). A flow along +x gives a positive shift that grows with the
    loading: 1.1, 2.6 and 4.9 um on the OCT example (``examples/oct_colony``, 50, 100
    and 150 mm^2/s); the same scans with their columns reversed, the zero-flow one
    included (the flow running against the image's x), -1.1, -2.6 and -4.9 um.

    Parameters
    ----------
    observed : array_like, shape (n, 2)
        Observed interface, mm.
    reference : array_like, shape (m, 2)
        Model's undeformed interface from foot to foot, mm.
    """
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.projection import closest_points

    obs = np.asarray(observed, dtype=float)
    _, near, _ = closest_points(obs, Interface.polyline(np.asarray(reference, dtype=float),
                                                        name="model reference"))
    w = np.clip(obs[:, 1], 0.0, None)
    return float(np.average(obs[:, 0] - near[:, 0], weights=w)) if w.sum() > 0 else 0.0


def mirrored_x(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``points`` (n, 2) mirrored in x and put on the reference's footprint: x becomes
    ``m_p + m_r - x`` (``m`` the middle of the first and last points, the feet), in
    reverse order. An interface traced from an image whose columns were reversed
    becomes the one the image would give the right way round, wherever the image's own
    middle was (the mirror's axis); one the right way round becomes its mirror image on
    the reference's footprint."""
    p = np.array(points, dtype=float)
    r = np.asarray(reference, dtype=float)
    p[:, 0] = 0.5 * float(p[0, 0] + p[-1, 0] + r[0, 0] + r[-1, 0]) - p[:, 0]
    return p[::-1]


def placement(observed: np.ndarray, reference: np.ndarray) -> Placement:
    """Compare an observed interface with the model's undeformed interface.

    Under flow the interface moves by a fraction of the colony's height and its
    feet, attached to the substrate, barely move; an image placed with a wrong
    origin or read in the wrong unit lies far off or at another scale. This
    measures both (:class:`Placement`); the caller decides what is too far.

    Parameters
    ----------
    observed : array_like, shape (n, 2)
        Observed interface (open, mm).
    reference : array_like, shape (m, 2)
        Model's undeformed interface from foot to foot (mm).
    """
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.projection import closest_points

    obs = np.asarray(observed, dtype=float)
    ref = np.asarray(reference, dtype=float)
    d, _, _ = closest_points(obs, Interface.polyline(ref, name="model reference"))
    ext_o = float(np.ptp(obs[:, 0]))
    ext_r = float(np.ptp(ref[:, 0])) or 1.0
    o = obs if obs[0, 0] <= obs[-1, 0] else obs[::-1]
    r = ref if ref[0, 0] <= ref[-1, 0] else ref[::-1]
    dx = 0.5 * float((o[0, 0] - r[0, 0]) + (o[-1, 0] - r[-1, 0]))
    dy = float(o[:, 1].min() - r[:, 1].min())
    return Placement(float(np.mean(np.abs(d))), ext_o / ext_r, (dx, dy))

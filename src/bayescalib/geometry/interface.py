"""Discretized interfaces: 2D polylines and 3D triangulated surfaces.

An :class:`Interface` is the geometric object every discrepancy measure of the
paper (Sec. 2.4: eq:eucliddist, eq:cppdist, eq:surfcurrontriang) compares: a
set of points with cells, segments in 2D and triangles in 3D. Lengths are in
mm throughout the package.

Orientation convention
----------------------
* 2D: the unit normal of segment ``(p0, p1)`` is the tangent
  ``t = p1 - p0`` rotated by +90 degrees, i.e. it points to the *left* of the
  direction of travel: ``n = (-t_y, t_x) / |t|``. A biofilm interface ordered
  upstream -> downstream (increasing x) over a patch attached to the floor
  therefore has normals pointing up, into the fluid. Equivalently, a closed
  curve around a solid body traversed clockwise has outward normals.
* 3D: the normal of triangle ``(p0, p1, p2)`` is
  ``(p1 - p0) x (p2 - p0) / |...|`` (right-hand rule); orient triangles so that
  it points into the fluid.

Every measure that is *signed* (Euclidean distance along the observed normal,
closest point projection) is positive when the model lies on the side the
observed normal points to.

Resampling (:meth:`Interface.resampled`) subdivides every element into equal
sub-elements whose size is at most a given spacing without changing the
geometry; the RKHS norm (eq:surfcurrontriang) needs this to be independent of
the input discretization (see :mod:`bayescalib.measures.currents`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

__all__ = ["Interface", "InterfaceError", "segment_intersections"]


class InterfaceError(ValueError):
    """An interface is malformed (shape, non-finite values, degenerate cells...)."""


@dataclass(frozen=True, eq=False)
class Interface:
    """A discretized interface (polyline in 2D, triangle surface in 3D).

    Parameters
    ----------
    points : ndarray, shape (n, d)
        Node coordinates in mm, ``d`` in {2, 3}.
    cells : ndarray of int, shape (m, d)
        Node indices of each cell: segments ``(i, j)`` for ``d = 2``,
        triangles ``(i, j, k)`` for ``d = 3``.
    name : str
        Free text used in error messages (e.g. the file it came from).

    Raises
    ------
    InterfaceError
        If shapes are inconsistent, coordinates are not finite, indices are out
        of range, fewer than one cell or two points are given, or a cell is
        degenerate (zero length/area, e.g. from duplicate consecutive points).
    """

    points: np.ndarray
    cells: np.ndarray
    name: str = field(default="interface", compare=False)

    def __post_init__(self) -> None:
        where = f"{self.name}: " if self.name else ""
        try:
            pts = np.array(self.points, dtype=float, copy=True)
        except (TypeError, ValueError) as exc:
            raise InterfaceError(f"{where}points are not numeric ({exc})") from None
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise InterfaceError(
                f"{where}points must have shape (n, 2) or (n, 3), got {pts.shape}"
            )
        if pts.shape[0] < 2:
            raise InterfaceError(
                f"{where}an interface needs at least 2 points, got {pts.shape[0]}"
            )
        bad = ~np.isfinite(pts).all(axis=1)
        if bad.any():
            raise InterfaceError(
                f"{where}{int(bad.sum())} point(s) have NaN/inf coordinates "
                f"(first at index {int(np.flatnonzero(bad)[0])})"
            )
        d = pts.shape[1]
        cells = np.asarray(self.cells)
        if cells.size == 0:
            raise InterfaceError(f"{where}an interface needs at least one cell")
        if not np.issubdtype(cells.dtype, np.integer) and not np.all(np.mod(cells, 1) == 0):
            raise InterfaceError(f"{where}cell indices must be integers")
        cells = np.array(cells, dtype=np.int64, copy=True)
        if cells.ndim != 2 or cells.shape[1] != d:
            kind = "segments (m, 2)" if d == 2 else "triangles (m, 3)"
            raise InterfaceError(f"{where}cells must be {kind} for {d}D points, got {cells.shape}")
        if cells.min() < 0 or cells.max() >= pts.shape[0]:
            raise InterfaceError(
                f"{where}cell indices must lie in [0, {pts.shape[0] - 1}], "
                f"got range [{cells.min()}, {cells.max()}]"
            )
        pts.setflags(write=False)
        cells.setflags(write=False)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cells", cells)
        meas = self.measures
        scale = float(np.ptp(pts, axis=0).max()) or 1.0
        tol = (1e-12 * scale) ** (d - 1)
        small = meas <= tol
        if small.any():
            i = int(np.flatnonzero(small)[0])
            what = "zero length (duplicate consecutive points?)" if d == 2 else "zero area"
            raise InterfaceError(
                f"{where}{int(small.sum())} degenerate cell(s) with {what}; "
                f"first is cell {i} with nodes {cells[i].tolist()}"
            )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def polyline(
        cls,
        points: np.ndarray,
        segments: np.ndarray | None = None,
        *,
        closed: bool = False,
        name: str = "interface",
    ) -> Interface:
        """A 2D polyline.

        Parameters
        ----------
        points : array_like, shape (n, 2)
            Node coordinates in mm.
        segments : array_like of int, shape (m, 2), optional
            Explicit segments. If None the points are an ordered curve:
            segments ``(i, i + 1)``, plus ``(n - 1, 0)`` when ``closed``.
        closed : bool
            Close the ordered curve (ignored when ``segments`` is given).
        """
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[-1] != 2:
            raise InterfaceError(f"{name}: polyline points must have shape (n, 2), got {pts.shape}")
        if segments is None:
            n = pts.shape[0]
            if n < 2:
                raise InterfaceError(f"{name}: an interface needs at least 2 points, got {n}")
            idx = np.arange(n)
            segments = np.stack([idx[:-1], idx[1:]], axis=1)
            if closed:
                if n < 3:
                    raise InterfaceError(f"{name}: a closed curve needs at least 3 points")
                segments = np.vstack([segments, [[n - 1, 0]]])
        return cls(pts, np.asarray(segments), name=name)

    @classmethod
    def surface(cls, points: np.ndarray, triangles: np.ndarray, *, name: str = "interface") -> Interface:
        """A 3D triangulated surface from ``points (n, 3)`` and ``triangles (m, 3)``."""
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[-1] != 3:
            raise InterfaceError(f"{name}: surface points must have shape (n, 3), got {pts.shape}")
        return cls(pts, np.asarray(triangles), name=name)

    # ------------------------------------------------------------------ geometry
    @property
    def dim(self) -> int:
        """Spatial dimension (2 or 3)."""
        return int(self.points.shape[1])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @cached_property
    def _area_vectors(self) -> np.ndarray:
        """Un-normalized normals, shape (m, d): length/area times unit normal."""
        p = self.points[self.cells]
        if self.dim == 2:
            t = p[:, 1] - p[:, 0]
            return np.stack([-t[:, 1], t[:, 0]], axis=1)
        return 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])

    @cached_property
    def centres(self) -> np.ndarray:
        """Cell centres (midpoints / centroids), shape (m, d), mm."""
        return self.points[self.cells].mean(axis=1)

    @cached_property
    def measures(self) -> np.ndarray:
        """Cell lengths (2D, mm) or areas (3D, mm^2), shape (m,)."""
        return np.linalg.norm(self._area_vectors, axis=1)

    @cached_property
    def normals(self) -> np.ndarray:
        """Unit cell normals, shape (m, d) (orientation: see module docstring)."""
        return self._area_vectors / self.measures[:, None]

    @property
    def current(self) -> np.ndarray:
        """Normals scaled by the cell measure (the discrete current), shape (m, d)."""
        return self._area_vectors

    @property
    def total_measure(self) -> float:
        """Total length (2D, mm) or area (3D, mm^2)."""
        return float(self.measures.sum())

    @property
    def bounds(self) -> np.ndarray:
        """Bounding box, shape (2, d): row 0 minimum, row 1 maximum."""
        return np.stack([self.points.min(axis=0), self.points.max(axis=0)])

    def is_chain(self) -> bool:
        """Whether the cells are the ordered curve ``(i, i+1)`` (optionally closed)."""
        if self.dim != 2:
            return False
        n, m = self.n_points, self.n_cells
        idx = np.arange(n)
        if m == n - 1:
            return bool(np.array_equal(self.cells, np.stack([idx[:-1], idx[1:]], axis=1)))
        if m == n:
            return bool(np.array_equal(self.cells, np.stack([idx, np.roll(idx, -1)], axis=1)))
        return False

    def arc_length(self) -> np.ndarray:
        """Cumulative arc length at the points of an ordered 2D curve, shape (n,), mm.

        Raises
        ------
        InterfaceError
            For surfaces or polylines whose segments are not the ordered chain
            ``(i, i + 1)``.
        """
        if self.dim != 2 or not self.is_chain():
            raise InterfaceError(
                f"{self.name}: arc_length needs an ordered 2D curve with segments (i, i+1)"
            )
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(seg)])

    # ------------------------------------------------------------------ transforms
    def transformed(self, rotation: np.ndarray | None = None, shift: np.ndarray | None = None) -> Interface:
        """Rigid motion ``x -> R x + shift`` (R orthogonal, det +1 keeps orientation)."""
        pts = self.points
        if rotation is not None:
            pts = pts @ np.asarray(rotation, dtype=float).T
        if shift is not None:
            pts = pts + np.asarray(shift, dtype=float)
        return Interface(pts, self.cells, name=self.name)

    def reversed(self) -> Interface:
        """Same geometry with flipped orientation (normals negated)."""
        return Interface(self.points, self.cells[:, ::-1], name=self.name)

    def resampled(self, spacing: float) -> Interface:
        """Subdivide every cell into equal sub-cells of size at most ``spacing``.

        2D: segment ``e`` of length ``L_e`` is split into ``k_e = ceil(L_e / spacing)``
        equal segments, i.e. by arc length with spacing ``<= spacing``. An ordered
        curve stays an ordered curve (original nodes are kept).
        3D: triangle ``e`` with longest edge ``L_e`` is split regularly into
        ``k_e^2`` congruent sub-triangles (``k_e = ceil(L_e / spacing)``; for
        ``k_e = 2^l`` this is ``l`` steps of midpoint subdivision), so every
        sub-triangle edge is ``<= spacing``. Sub-triangles are stored per parent
        (shared nodes are duplicated; the result need not be conforming, which
        the measures do not require).

        The geometry (and the current, sum of scaled normals) is unchanged;
        orientation is preserved.

        Parameters
        ----------
        spacing : float
            Maximum sub-cell size in mm, > 0.
        """
        if not np.isfinite(spacing) or spacing <= 0:
            raise InterfaceError(f"{self.name}: resampling spacing must be > 0, got {spacing}")
        if self.dim == 2:
            return self._resample_curve(spacing)
        return self._resample_surface(spacing)

    def _resample_curve(self, h: float) -> Interface:
        p = self.points[self.cells]  # (m, 2, 2)
        k = np.maximum(1, np.ceil(self.measures / h - 1e-9)).astype(np.int64)
        if np.all(k == 1):
            return self
        if self.is_chain():
            # keep an ordered curve: points of segment e are p0 + (j/k_e)(p1 - p0), j < k_e
            seg = np.repeat(np.arange(self.n_cells), k)
            j = np.arange(seg.size) - np.repeat(np.cumsum(k) - k, k)
            frac = (j / k[seg])[:, None]
            pts = p[seg, 0] + frac * (p[seg, 1] - p[seg, 0])
            closed = self.n_cells == self.n_points
            if not closed:
                pts = np.vstack([pts, self.points[-1]])
            return Interface.polyline(pts, closed=closed, name=self.name)
        seg = np.repeat(np.arange(self.n_cells), k)
        j = np.arange(seg.size) - np.repeat(np.cumsum(k) - k, k)
        a = p[seg, 0] + (j / k[seg])[:, None] * (p[seg, 1] - p[seg, 0])
        b = p[seg, 0] + ((j + 1) / k[seg])[:, None] * (p[seg, 1] - p[seg, 0])
        pts = np.empty((2 * seg.size, 2))
        pts[0::2], pts[1::2] = a, b
        cells = np.arange(2 * seg.size).reshape(-1, 2)
        return Interface(pts, cells, name=self.name)

    def _resample_surface(self, h: float) -> Interface:
        p = self.points[self.cells]  # (m, 3, 3)
        edges = np.stack(
            [p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], axis=1
        )
        longest = np.linalg.norm(edges, axis=2).max(axis=1)
        k_all = np.maximum(1, np.ceil(longest / h - 1e-9)).astype(np.int64)
        if np.all(k_all == 1):
            return self
        out_pts: list[np.ndarray] = []
        out_tri: list[np.ndarray] = []
        offset = 0
        for k in np.unique(k_all):
            sel = np.flatnonzero(k_all == k)
            bary, tris = _triangle_lattice(int(k))
            # points: (len(sel), n_lattice, 3)
            pts = np.einsum("lb,ebd->eld", bary, p[sel])
            nl = bary.shape[0]
            out_pts.append(pts.reshape(-1, 3))
            out_tri.append(
                (tris[None, :, :] + (offset + nl * np.arange(sel.size))[:, None, None]).reshape(-1, 3)
            )
            offset += nl * sel.size
        return Interface(np.vstack(out_pts), np.vstack(out_tri), name=self.name)


def _triangle_lattice(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric lattice of the regular ``k``-subdivision of a triangle.

    Returns
    -------
    bary : ndarray, shape ((k+1)(k+2)/2, 3)
        Barycentric weights of the lattice nodes w.r.t. the parent vertices.
    tris : ndarray of int, shape (k^2, 3)
        Sub-triangles with the parent's orientation.
    """
    ij = [(i, j) for i in range(k + 1) for j in range(k + 1 - i)]
    index = {q: n for n, q in enumerate(ij)}
    bary = np.array([[1 - (i + j) / k, i / k, j / k] for i, j in ij])
    tris = []
    for i in range(k):
        for j in range(k - i):
            tris.append([index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]])
            if i + j + 1 < k:
                tris.append([index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]])
    return bary, np.array(tris, dtype=np.int64)


#: most candidate segment pairs the self-intersection test examines (each is a few
#: dozen bytes and flops); past it the curve is refused rather than checked for minutes
MAX_SEGMENT_PAIRS = 50_000_000


def segment_intersections(interface: Interface, *, max_report: int = 1) -> list[tuple[int, int]]:
    """Pairs of non-adjacent 2D segments that intersect (self-intersections).

    Segments sharing a node are not tested against each other. The test is
    exact up to round-off (sign of orientation determinants); touching counts
    as intersecting. Candidates come from a sweep along the curve's longer axis
    (segments sorted by their lower end; a segment meets only those that start
    before it ends), so a curve costs about n log n, not n^2.

    Parameters
    ----------
    interface : Interface
        A 2D polyline.
    max_report : int
        Stop after this many pairs.

    Returns
    -------
    list of (int, int)
        Cell index pairs ``(i, j)``, ``i < j``, in sweep order.

    Raises
    ------
    InterfaceError
        If the sweep leaves more than :data:`MAX_SEGMENT_PAIRS` candidate pairs (a
        curve folded onto itself many times, or far too many points).
    """
    if interface.dim != 2:
        raise InterfaceError("segment_intersections is for 2D polylines")
    p = interface.points[interface.cells]
    a, b = p[:, 0], p[:, 1]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    m = p.shape[0]
    if m < 2:
        return []
    ax = int(np.argmax(np.ptp(interface.points, axis=0)))  # sweep along the longer axis
    order = np.argsort(lo[:, ax], kind="stable")
    lo_s = lo[order, ax]
    # sorted position k: candidates are the sorted positions k+1 .. end[k]-1
    end = np.searchsorted(lo_s, hi[order, ax], side="right")
    counts = np.maximum(end - np.arange(m) - 1, 0)
    total = int(counts.sum())
    if total > MAX_SEGMENT_PAIRS:
        raise InterfaceError(
            f"{interface.name}: the self-intersection test would examine {total:,} segment "
            f"pairs (limit {MAX_SEGMENT_PAIRS:,}) for {m:,} segments: the curve has far more "
            "points than an interface needs, or folds onto itself many times; resample it")
    found: list[tuple[int, int]] = []
    cells = interface.cells

    def orient(p_, q_, r_):
        return (q_[:, 0] - p_[:, 0]) * (r_[:, 1] - p_[:, 1]) - (q_[:, 1] - p_[:, 1]) * (
            r_[:, 0] - p_[:, 0]
        )

    starts = np.cumsum(counts) - counts
    block = 2_000_000
    k0 = 0
    while k0 < m:
        # sorted positions k0..k1-1 whose candidates fit in one block of pairs
        k1 = int(np.searchsorted(starts, starts[k0] + block, side="right"))
        k1 = max(k1, k0 + 1)
        c = counts[k0:k1]
        if c.sum():
            ks = np.repeat(np.arange(k0, k1), c)
            ls = ks + 1 + (np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c))
            ii, jj = order[ks], order[ls]
            o = 1 - ax
            keep = (lo[ii, o] <= hi[jj, o]) & (lo[jj, o] <= hi[ii, o])
            keep &= ~(cells[ii][:, :, None] == cells[jj][:, None, :]).any(axis=(1, 2))
            ii, jj = ii[keep], jj[keep]
            hit = (orient(a[ii], b[ii], a[jj]) * orient(a[ii], b[ii], b[jj]) <= 0.0) & (
                orient(a[jj], b[jj], a[ii]) * orient(a[jj], b[jj], b[ii]) <= 0.0)
            for x, y in zip(ii[hit], jj[hit]):
                found.append((int(min(x, y)), int(max(x, y))))
                if len(found) >= max_report:
                    return found
        k0 = k1
    return found
    return found

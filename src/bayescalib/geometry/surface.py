"""Observed 3D interfaces: a colony's triangulated surface, and its plane sections.

The 3D model (:mod:`bayescalib.models.fsi.geometry3d`) has the flow along ``x``, the
height ``y`` (up, the floor is ``y = 0``) and the width ``z``; its interface is the
colony's surface *without* the base on the floor, triangles oriented so that the
normal points out of the colony into the fluid (:class:`Interface`). An observed
surface is brought into that form here, from whatever gave it (marching cubes of an OCT
volume, :mod:`bayescalib.geometry.volume`; a surface file,
:mod:`bayescalib.io.surfaces`), by :func:`colony_surface`:

1. *Cut at the substrate.* Everything at or below the floor plane ``y = floor`` is
   clipped away (``vtkClipPolyData`` with the plane ``y = floor + eps``, ``eps`` =
   :data:`CLIP_EPS` times the surface's extent, so that a flat base lying exactly on
   the floor goes as a whole); triangles crossing the plane are cut along it, so the
   colony's rim lies on the floor plane.
2. *One colony.* The triangles are grouped into connected components (triangles that
   share an edge or a vertex). More than one is refused with their number and sizes
   (triangles, area), unless ``component`` picks one (0 = the largest by area).
3. *Not cut off.* Every boundary edge (an edge of one triangle only) must lie on the
   floor plane: a rim above it is a colony cut off by the field of view (or a hole in
   the mesh), refused with its height above the floor.
4. *Smoothing* (optional, ``iterations > 0``): Taubin's lambda|mu smoothing
   (Taubin 1995), ``iterations`` pairs of a shrinking step ``lambda = 0.5`` and an
   inflating step ``mu = -0.53`` of the uniform umbrella operator: a low-pass filter
   of the mesh that removes the staircase of a voxel surface without the shrinkage
   of plain Laplacian smoothing (the enclosed volume changes by well under 1 % on the
   tests' half-ellipsoids; ``info["volume_change"]`` reports it). Rim vertices are
   smoothed along the rim only (their neighbours on the rim), so the rim stays in the
   floor plane.
5. *Orientation.* The volume between the surface and the floor,
   ``V = 1/3 sum_t A_t n_t . (c_t - p_f)`` (``c_t`` the triangle's centroid, ``p_f`` a
   point of the floor; exact for flat triangles, the floor face adds nothing), is
   positive when the normals point out of the colony; a negative one flips every
   triangle.

:func:`plane_section` cuts a surface with a plane: the observed 2D B-scan through a 3D
colony, as the 2D interface the 2D model is compared with (ordered from the upstream
to the downstream foot, normals into the fluid).

Lengths are in mm; :data:`UNITS` converts the other length units.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface, InterfaceError

__all__ = ["CLIP_EPS", "TAUBIN_ITERATIONS", "TAUBIN_LAMBDA", "TAUBIN_MU", "UNITS",
           "SurfaceError", "boundary_edges", "colony_surface", "downstream_lean", "enclosed_volume",
           "mesh_components", "pick_component", "plane_section", "surface_above",
           "surface_placement",
           "taubin_smooth", "unit_factor", "upper_shift"]

#: length unit -> factor to mm
UNITS: dict[str, float] = {"m": 1000.0, "mm": 1.0, "um": 1.0e-3}
#: the clipping plane lies this share of the surface's extent above the floor
CLIP_EPS = 1e-6
#: Taubin smoothing: the shrinking and the inflating step (pass-band k_PB ~ 0.1)
TAUBIN_LAMBDA = 0.5
TAUBIN_MU = -0.53
#: default smoothing iterations (pairs of steps) for a marching-cubes surface
TAUBIN_ITERATIONS = 20


class SurfaceError(ValueError):
    """A surface or a volume that cannot become an observed interface; the message names
    the source, the value and what to do."""


def unit_factor(unit: str | None, where: str, what: str = "units") -> float:
    """mm per ``unit``; a missing or unknown unit raises :class:`SurfaceError`."""
    if unit is None:
        raise SurfaceError(f"{where}: no length unit given: pass {what}= one of "
                           f"{', '.join(repr(u) for u in UNITS)} (the unit of the coordinates)")
    if unit not in UNITS:
        raise SurfaceError(f"{where}: unknown length unit {unit!r} ({what}); use one of "
                           f"{', '.join(repr(u) for u in UNITS)}")
    return UNITS[unit]


# ------------------------------------------------------------------ mesh topology
def _edges(triangles: np.ndarray) -> np.ndarray:
    """All directed triangle edges, shape (3m, 2)."""
    t = np.asarray(triangles, dtype=np.int64)
    return np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """Edges used by one triangle only (the rim of an open surface), shape (k, 2)."""
    e = np.sort(_edges(triangles), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    return uniq[count == 1]


def mesh_components(triangles: np.ndarray, n_points: int) -> np.ndarray:
    """Connected component of every triangle (sharing a vertex connects), shape (m,);
    labels 0, 1, ... in order of first appearance."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    t = np.asarray(triangles, dtype=np.int64)
    e = _edges(t)
    g = coo_matrix((np.ones(e.shape[0]), (e[:, 0], e[:, 1])), shape=(n_points, n_points))
    _, lab = connected_components(g, directed=False)
    return lab[t[:, 0]]


def _triangle_areas(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p = points[triangles]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def _compact(points: np.ndarray, triangles: np.ndarray, keep: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """The triangles ``keep`` (bool, (m,)) and the points they use, renumbered."""
    tri = triangles[keep]
    used = np.unique(tri)
    remap = -np.ones(points.shape[0], dtype=np.int64)
    remap[used] = np.arange(used.size)
    return points[used], remap[tri]


# ------------------------------------------------------------------ operations
def clip_below(points: np.ndarray, triangles: np.ndarray, y: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """The part of a triangle surface above the plane ``y`` (``vtkClipPolyData``;
    crossing triangles are cut along the plane). Shapes (n, 3) mm and (m, 3)."""
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy

    pd = vtk.vtkPolyData()
    vp = vtk.vtkPoints()
    vp.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=float), deep=True))
    pd.SetPoints(vp)
    ca = vtk.vtkCellArray()
    ca.SetData(3, numpy_to_vtkIdTypeArray(np.ascontiguousarray(triangles.ravel()).astype(
        vtk_to_numpy(vtk.vtkIdTypeArray()).dtype), deep=True))
    pd.SetPolys(ca)
    plane = vtk.vtkPlane()
    plane.SetOrigin(0.0, float(y), 0.0)
    plane.SetNormal(0.0, 1.0, 0.0)
    clip = vtk.vtkClipPolyData()
    clip.SetInputData(pd)
    clip.SetClipFunction(plane)
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(clip.GetOutputPort())
    clean = vtk.vtkCleanPolyData()  # merge the points the clip made twice
    clean.SetInputConnection(tri.GetOutputPort())
    clean.Update()
    out = clean.GetOutput()
    if out.GetNumberOfPolys() == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    pts = vtk_to_numpy(out.GetPoints().GetData()).astype(float)
    tris = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).astype(np.int64).reshape(-1, 3)
    return pts, tris


def taubin_smooth(points: np.ndarray, triangles: np.ndarray, iterations: int = TAUBIN_ITERATIONS,
                  lam: float = TAUBIN_LAMBDA, mu: float = TAUBIN_MU) -> np.ndarray:
    """Taubin lambda|mu smoothing (module docstring, step 4).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Vertices, mm.
    triangles : ndarray of int, shape (m, 3)
    iterations : int
        Pairs of steps (>= 0).
    lam, mu : float
        The shrinking (> 0) and the inflating (< -lam) step.

    Returns
    -------
    ndarray, shape (n, 3)
        Smoothed vertices, mm; rim vertices move along the rim only.
    """
    from scipy.sparse import coo_matrix, diags

    if int(iterations) < 0:
        raise SurfaceError(f"smoothing iterations must be >= 0, got {iterations}")
    x = np.array(points, dtype=float)
    n = x.shape[0]
    e = np.sort(_edges(triangles), axis=1)
    e = np.unique(e, axis=0)
    rim = boundary_edges(triangles)
    on_rim = np.zeros(n, dtype=bool)
    on_rim[rim.ravel()] = True
    # an interior vertex averages all its edge neighbours, a rim vertex its rim neighbours
    a_in, b_in = ~on_rim[e[:, 0]], ~on_rim[e[:, 1]]
    rows = np.concatenate([e[a_in, 0], e[b_in, 1], rim[:, 0], rim[:, 1]])
    cols = np.concatenate([e[a_in, 1], e[b_in, 0], rim[:, 1], rim[:, 0]])
    a = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)).tocsr()
    deg = np.asarray(a.sum(axis=1)).ravel()
    a = diags(1.0 / np.maximum(deg, 1)) @ a
    moving = deg > 0
    for _ in range(int(iterations)):
        for f in (lam, mu):
            x[moving] += f * (a @ x - x)[moving]
    return x


def enclosed_volume(points: np.ndarray, triangles: np.ndarray, floor: float) -> float:
    """Signed volume between a surface and the floor plane ``y = floor`` (module
    docstring, step 5), mm^3: positive for normals out of the colony."""
    p = np.asarray(points, dtype=float)[np.asarray(triangles)]
    area_vec = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    c = p.mean(axis=1)
    c[:, 1] -= float(floor)
    return float(np.einsum("md,md->", area_vec, c) / 3.0)


def pick_component(sizes: np.ndarray, component: int | None, name: str, *, what: str,
                   describe: Any, hint: str) -> int:
    """The index of the component to keep: the only one, or ``component`` (0 = the
    largest of ``sizes``); several without a choice, or a choice out of range, raise
    :class:`SurfaceError` listing the largest five (``describe(index)``), ``what`` they are
    and ``hint`` (what else to do)."""
    order = np.argsort(-np.asarray(sizes), kind="stable")
    n = len(order)
    if n > 1 and component is None:
        listed = ", ".join(f"#{k}: {describe(j)}" for k, j in enumerate(order[:5]))
        raise SurfaceError(
            f"{name}: {n} {what}; by decreasing size {listed}{', ...' if n > 5 else ''}): one "
            f"colony is expected; pick one with component=k (0 = the largest), {hint}")
    k = 0 if component is None else int(component)
    if not 0 <= k < n:
        raise SurfaceError(f"{name}: component={component} but there are {n} component(s) "
                           f"(0 .. {n - 1})")
    return int(order[k])


def colony_surface(
    points: np.ndarray,
    triangles: np.ndarray,
    *,
    floor: float | None,
    component: int | None = None,
    iterations: int = 0,
    rim_tol: float | None = None,
    name: str = "surface",
) -> tuple[Interface, dict[str, Any]]:
    """A colony's surface from a triangle mesh (module docstring, steps 1-5).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Vertices in mm (x flow, y up, z across).
    triangles : ndarray of int, shape (m, 3)
    floor : float or None
        y of the floor plane, mm: the part at or below it is cut away. None: nothing is
        cut, the surface must be open with its rim on one plane ``y = const`` (the
        lowest rim vertex), which is the floor.
    component : int, optional
        Which connected component to keep, by decreasing area (0 = the largest); None:
        more than one is an error.
    iterations : int
        Taubin smoothing iterations (0 = none).
    rim_tol : float, optional
        Largest height of a rim vertex above the floor, mm (default ``2e-6`` times the
        surface's extent).
    name : str
        The source, in error messages.

    Returns
    -------
    surface : Interface
        Triangles ``(m, 3)`` over vertices ``(n, 3)`` in mm, normals into the fluid.
    info : dict
        ``floor_mm``, ``components`` (count), ``component_areas_mm2`` (decreasing),
        ``component``, ``smoothing_iterations``, ``volume_mm3``, ``area_mm2``,
        ``volume_change`` (relative, by the smoothing), ``flipped``.

    Raises
    ------
    SurfaceError
        Empty surface (nothing above the floor), several components, a rim above the
        floor (cut off), a closed surface with ``floor=None``.
    """
    pts = np.asarray(points, dtype=float)
    tri = np.asarray(triangles, dtype=np.int64)
    if pts.ndim != 2 or pts.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3:
        raise SurfaceError(f"{name}: expected points (n, 3) and triangles (m, 3), got "
                           f"{pts.shape} and {tri.shape}")
    if tri.shape[0] == 0:
        raise SurfaceError(f"{name}: the surface has no triangles (empty)")
    if not np.isfinite(pts).all():
        raise SurfaceError(f"{name}: NaN/inf vertex coordinates")
    extent = float(np.ptp(pts, axis=0).max()) or 1.0
    if floor is not None:
        y_f = float(floor)
        if not np.isfinite(y_f):
            raise SurfaceError(f"{name}: floor must be a finite y (mm), got {floor}")
        pts, tri = clip_below(pts, tri, y_f + CLIP_EPS * extent)
        if tri.shape[0] == 0:
            raise SurfaceError(f"{name}: nothing of the surface lies above the floor "
                               f"y = {y_f:g} mm (its y range is {float(points[:, 1].min()):g} "
                               f"to {float(points[:, 1].max()):g} mm)")
    area = _triangle_areas(pts, tri)
    good = area > (1e-12 * extent) ** 2
    pts, tri = _compact(pts, tri, good)
    area = area[good]
    lab = mesh_components(tri, pts.shape[0])
    sizes = np.bincount(lab, weights=area)
    counts = np.bincount(lab)
    chosen = pick_component(
        sizes, component, name, what="separate pieces (connected components",
        describe=lambda j: f"{int(counts[j])} triangles, {sizes[j]:.4g} mm^2",
        hint="or crop the data to one colony")
    order = np.argsort(-sizes, kind="stable")
    k = int(np.flatnonzero(order == chosen)[0])
    pts, tri = _compact(pts, tri, lab == chosen)
    rim = boundary_edges(tri)
    if floor is None:
        if rim.size == 0:
            raise SurfaceError(f"{name}: the surface is closed (it includes the colony's base "
                               "on the substrate): give floor= (a y, or 'auto' for its "
                               "lowest point) to cut the base off")
        y_f = float(pts[np.unique(rim), 1].min())
    else:
        y_f = float(floor) + CLIP_EPS * extent
    tol = CLIP_EPS * extent * 2 if rim_tol is None else float(rim_tol)
    if rim.size:
        high = pts[np.unique(rim), 1] - y_f
        if high.max() > tol:
            raise SurfaceError(
                f"{name}: the surface has {int(np.count_nonzero(high > tol))} rim vertices "
                f"above the floor y = {y_f:g} mm (up to {high.max():.4g} mm above it): the "
                "colony is cut off (by the field of view or the volume's border) or the mesh "
                "has a hole; only the rim on the floor may be open")
    v0 = enclosed_volume(pts, tri, y_f)
    if iterations:
        pts = taubin_smooth(pts, tri, iterations)
    v1 = enclosed_volume(pts, tri, y_f)
    flipped = v1 < 0
    if flipped:
        tri = tri[:, ::-1]
    try:
        surf = Interface.surface(pts, tri, name=name)
    except InterfaceError as exc:
        raise SurfaceError(str(exc)) from None
    info = {"floor_mm": y_f, "components": len(order),
            "component_areas_mm2": [float(sizes[j]) for j in order], "component": k,
            "smoothing_iterations": int(iterations), "volume_mm3": abs(v1),
            "area_mm2": surf.total_measure,
            "volume_change": float((abs(v1) - abs(v0)) / abs(v0)) if v0 else 0.0,
            "flipped": bool(flipped)}
    return surf, info


def surface_above(surface: Interface, y: float) -> Interface:
    """The part of a surface above the plane ``y`` (mm), triangles crossing it cut along
    it (:func:`clip_below`); the surface itself when nothing of it lies above."""
    pts, tri = clip_below(surface.points, surface.cells, y)
    if tri.shape[0] == 0:
        return surface
    return Interface.surface(pts, tri, name=f"{surface.name} above y = {y:g} mm")


def surface_placement(observed: Interface, reference: Interface) -> Any:
    """Compare an observed colony surface with the model's undeformed one (the 3D
    :func:`bayescalib.geometry.outline.placement`): under flow the surface moves by a
    fraction of the colony's height and its rim, attached to the floor, barely moves; a
    wrong origin or unit moves or scales it as a whole.

    Parameters
    ----------
    observed, reference : Interface
        Surfaces (vertices in mm).

    Returns
    -------
    Placement
        ``mean_distance``: mean distance of the observed vertices from the reference
        surface (mm); ``extent_ratio``: the footprint's size over the model's, the
        geometric mean of the x and z extents' ratios; ``offset`` (dx, dy, dz): the shift
        of the footprint's centre (the middle of the x and z extents) and of the top (an
        observed surface may be cut above the floor, a flow lowers the top a little).
    """
    from bayescalib.geometry.outline import Placement
    from bayescalib.geometry.projection import closest_points

    obs, ref = observed.points, reference.points
    d, _, _ = closest_points(obs, reference)
    ratio = [float(np.ptp(obs[:, a])) / (float(np.ptp(ref[:, a])) or 1.0) for a in (0, 2)]
    mid = [0.5 * (float(obs[:, a].min() + obs[:, a].max()) - float(ref[:, a].min()
                                                                  + ref[:, a].max())) for a in (0, 2)]
    dy = float(obs[:, 1].max() - ref[:, 1].max())  # the top: a surface may be cut above the floor
    return Placement(float(np.mean(np.abs(d))), float(np.sqrt(ratio[0] * ratio[1])),
                     (mid[0], dy, mid[1]))


def downstream_lean(observed: Interface, reference: Interface) -> float:
    """How far an observed colony's upper half lies downstream (+x, the flow) of its base,
    compared with the model's undeformed colony, mm (:func:`upper_shift`'s x).

    A flow along +x bends the colony downstream, its top the most, while its base stays
    put: the lean grows with the loading and is positive. On the 3D example recording
    (``examples/oct_colony3d`` on the coarse mesh, the model's colony from its zero-flow
    volume): -0.2 um at zero flow, 5.1 and 14.3 um at 50 and 100 mm^3/s, -6.6 and -15.9
    um for the same volumes with their columns reversed (x against the flow). Unlike the
    mean distance from the model's colony (:func:`surface_placement`), it is not blurred
    by the geometry's own misfit (7 um there at every loading)."""
    return upper_shift(observed, reference)[0]


def upper_shift(observed: Interface, reference: Interface) -> tuple[float, float]:
    """The shift (x, z) of an observed colony's upper half from the model's undeformed
    colony's, relative to their bases, mm: the area-weighted centre of the triangles
    above half the reference's height less that of the triangles below a quarter of it,
    observed minus reference; a colony moved as a whole (a wrong origin, which
    :func:`surface_placement` measures) has none, and a speck at the foot barely counts. Under a flow along
    x the x-shift is the downstream lean (:func:`downstream_lean`) and the z-shift about
    nil (0.1 um on the 3D example recording); a z-shift well above the x-shift is a
    colony bent across the flow: a volume whose x and z axes are swapped."""
    half = 0.5 * float(reference.points[:, 1].max())

    def centre(surface: Interface) -> np.ndarray:
        c, w = surface.centres, surface.measures
        upper = c[:, 1] > half
        if not upper.any():
            upper = np.ones(len(c), dtype=bool)
        lower = c[:, 1] < 0.5 * half  # the base, which the flow moves least
        lower = lower if lower.any() else ~upper if (~upper).any() else upper
        return (np.average(c[upper][:, [0, 2]], axis=0, weights=w[upper])
                - np.average(c[lower][:, [0, 2]], axis=0, weights=w[lower]))

    d = centre(observed) - centre(reference)
    return float(d[0]), float(d[1])


# ------------------------------------------------------------------ plane sections
def plane_section(
    surface: Interface,
    point: np.ndarray,
    normal: np.ndarray = (0.0, 0.0, 1.0),
    *,
    up: np.ndarray = (0.0, 1.0, 0.0),
    flow: np.ndarray = (1.0, 0.0, 0.0),
    name: str | None = None,
) -> Interface:
    """The intersection of a surface with a plane, as a 2D interface (a B-scan).

    In-plane coordinates: ``v`` along ``up`` projected into the plane, ``u`` the
    in-plane direction across it that points downstream (``u . flow > 0``), and a point
    ``X`` maps to ``(X . e_u, X . e_v)``; for the plane ``z = z0`` that is ``(x, y)``,
    the 2D model's coordinates. Each triangle crossing the plane gives a segment between
    the points where two of its edges cross it (vertices exactly on the plane count as
    above it, so a shared edge gives one point); the segments are chained through their
    shared edges and oriented so that the 2D normal (left of travel, the convention of
    :class:`Interface`) is the in-plane part of the surface normal: into the fluid, and
    a colony's section runs from its upstream foot to its downstream foot.

    Parameters
    ----------
    surface : Interface
        A 3D triangle surface, mm.
    point : array_like, shape (3,)
        A point of the plane, mm (e.g. ``(0, 0, z0)``).
    normal : array_like, shape (3,)
        The plane's normal (any length; its sign does not matter).
    up, flow : array_like, shape (3,)
        The height and the flow direction of the model (default y and x).
    name : str, optional
        Name of the result (default: the surface's with the plane).

    Returns
    -------
    Interface
        2D ordered polyline ``(k, 2)`` in mm (closed when the section is a loop).

    Raises
    ------
    SurfaceError
        The plane misses the surface, is parallel to ``up``'s normal plane, or cuts it in
        more than one piece (the pieces' number and u ranges are given).
    """
    if surface.dim != 3:
        raise SurfaceError(f"{surface.name}: plane_section needs a 3D surface")
    n = np.asarray(normal, dtype=float)
    p0 = np.asarray(point, dtype=float)
    if n.shape != (3,) or p0.shape != (3,) or not np.linalg.norm(n) > 0:
        raise SurfaceError(f"{surface.name}: the plane needs a point (3,) and a non-zero "
                           f"normal (3,), got {p0.tolist()} and {n.tolist()}")
    n = n / np.linalg.norm(n)
    e_v = np.asarray(up, dtype=float) - np.dot(up, n) * n
    if np.linalg.norm(e_v) < 1e-9:
        raise SurfaceError(f"{surface.name}: the plane with normal {n.tolist()} is "
                           "horizontal (normal along up): a B-scan plane contains the "
                           "height direction")
    e_v /= np.linalg.norm(e_v)
    e_u = np.cross(e_v, n)
    if np.dot(e_u, flow) < 0:
        n, e_u = -n, -e_u
    label = name or f"{surface.name} at the plane through {p0.tolist()} normal {n.tolist()}"
    pts, tri = surface.points, surface.cells
    s = (pts - p0) @ n
    above = s >= 0
    cnt = above[tri].sum(axis=1)
    cut = np.flatnonzero((cnt == 1) | (cnt == 2))
    if cut.size == 0:
        raise SurfaceError(f"{label}: the plane misses the surface (signed distances of its "
                           f"vertices {s.min():.4g} to {s.max():.4g} mm)")
    t = tri[cut]
    # in the triangle's vertex order one edge crosses the plane upwards (below -> above)
    # and one downwards; with the triangle's normal n_t the segment from the upward to the
    # downward crossing runs along n_t x n (its left is the in-plane part of n_t). Taken
    # from the vertex order, not the points, this holds for zero-length segments too (a
    # vertex on the plane) and makes each crossing edge the end of one segment and the
    # start of the next (its two triangles traverse it in opposite directions)
    k = np.arange(t.shape[0])
    up = np.zeros((t.shape[0], 2), dtype=np.int64)
    down = np.zeros((t.shape[0], 2), dtype=np.int64)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        a_i, a_j = above[t[:, i]], above[t[:, j]]
        pair = np.sort(t[:, [i, j]], axis=1)
        up[k[~a_i & a_j]] = pair[~a_i & a_j]
        down[k[a_i & ~a_j]] = pair[a_i & ~a_j]
    keys, inv = np.unique(np.vstack([up, down]), axis=0, return_inverse=True)
    inv = inv.reshape(2, -1).T  # (segments, [from, to])
    sa, sb = s[keys[:, 0]], s[keys[:, 1]]
    w = (sa / (sa - sb))[:, None]
    xk = pts[keys[:, 0]] + w * (pts[keys[:, 1]] - pts[keys[:, 0]])
    nxt = -np.ones(keys.shape[0], dtype=np.int64)
    has_in = np.zeros(keys.shape[0], dtype=bool)
    nxt[inv[:, 0]] = inv[:, 1]
    has_in[inv[:, 1]] = True
    seen = np.zeros(keys.shape[0], dtype=bool)
    chains: list[tuple[list[int], bool]] = []
    for start in list(np.flatnonzero(~has_in)) + list(range(keys.shape[0])):
        if seen[start]:
            continue
        chain = [int(start)]
        seen[start] = True
        cur = nxt[start]
        while cur >= 0 and not seen[cur]:
            chain.append(int(cur))
            seen[cur] = True
            cur = nxt[cur]
        chains.append((chain, bool(cur == start)))
    uv = np.column_stack([xk @ e_u, xk @ e_v])
    # points where the plane passes through a vertex repeat (two edges, one point)
    if len(chains) > 1:
        ranges = "; ".join(f"u {uv[c, 0].min():.4g} to {uv[c, 0].max():.4g} mm ({len(c)} points)"
                           for c, _ in chains[:5])
        raise SurfaceError(f"{label}: the plane cuts the surface in {len(chains)} pieces "
                           f"({ranges}): one curve is expected (move the plane, or cut a "
                           "surface of one colony)")
    chain, closed = chains[0]
    curve = uv[chain]
    keep = np.r_[True, np.linalg.norm(np.diff(curve, axis=0), axis=1) > 1e-12 * (
        float(np.ptp(curve, axis=0).max()) or 1.0)]
    curve = curve[keep]
    if closed and curve.shape[0] > 1 and np.allclose(curve[0], curve[-1]):
        curve = curve[:-1]
    try:
        return Interface.polyline(curve, closed=closed and curve.shape[0] >= 3, name=label)
    except InterfaceError as exc:
        raise SurfaceError(str(exc)) from None

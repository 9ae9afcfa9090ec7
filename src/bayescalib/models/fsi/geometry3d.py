"""3D flow cell: a rectangular channel with a half-ellipsoidal or scanned colony on its floor.

Domain: the box ``[0, L] x [0, H] x [0, W]`` (length ``x``, height ``y``, width ``z``;
lengths in mm; ``geometry.length``, ``channel_height``, ``channel_width``) with the
biofilm colony attached to the floor ``y = 0``. The colony is the upper half
(``y >= 0``) of the ellipsoid

    ((x - x_c) / a)^2 + (y / b)^2 + ((z - z_c) / c)^2 <= 1,

``a = width / 2`` (along the flow), ``b = height``, ``c = depth / 2`` (across the
channel), centre ``(x_c, 0, z_c)`` = ``(centre, 0, centre_z)`` (``centre_z`` null: the
middle of the width, ``W / 2``). It is an exact OpenCascade ellipsoid cut by the
channel box, so the mesh is curved onto the true surface (``mesh.Curve``).

``shape: ridge`` is the 2D model's half-ellipse (width, height, centre) extruded across
the whole width: a colony that touches both side walls. With symmetry side walls
(``side_walls: slip``: ``u_z = d_z = 0`` there, the other components free) its solution
does not depend on z and is the 2D plane-strain solution at the rate ``Q / W`` per
unit width, which makes it the 3D model's check against the 2D one. Its side faces
are part of ``side``.

``shape: scan`` is the colony of a recording at zero flow: its triangulated surface
(``geometry.scan``) taken as a smoothed height field over the floor, continued below
it, filled into ``geometry.height_field`` when the study is read, and made into a
B-spline cutter solid (:mod:`bayescalib.models.fsi.scan3d`); ``colony = cutter * box``
and ``fluid = box - cutter`` as for the ellipsoid.

Boundary names: ``inlet`` (x = 0), ``outlet`` (x = L), ``top`` (y = H), ``floor`` (the
fluid's part of y = 0), ``side`` (z = 0 and z = W), ``biofilm_floor`` (the clamped
base of the colony, an ellipse in y = 0) and ``interface`` (fluid–biofilm). Regions:
``fluid`` and ``biofilm``. Tetrahedral mesh, graded from ``h_interface`` on the
interface and the base to ``h_solid`` inside the colony and ``h_bulk`` elsewhere.

The interface output is a triangulated surface: the vertices of the mesh's boundary
triangles on ``interface`` (the straight-sided triangles through the curved elements'
vertices), numbered ``0 .. n-1``, and the triangles ``(m, 3)`` into them, oriented by
the right-hand rule so that the normal points out of the colony into the fluid (away
from the fourth vertex of the biofilm tetrahedron each triangle bounds, whatever the
colony's shape) (the
convention of :class:`bayescalib.geometry.interface.Interface`, which the RKHS
surface-current measure takes as it is).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bayescalib.models.fsi.geometry import BiofilmMesh, _outline_face, generate_mesh

__all__ = ["build_mesh_3d", "colony_axes", "interface_surface", "reference_surface"]


def colony_axes(geometry: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Centre and semi-axes of the half-ellipsoidal colony.

    Parameters
    ----------
    geometry : dict
        Validated ``geometry`` section with ``dim: 3`` (mm).

    Returns
    -------
    centre : ndarray, shape (3,)
        ``(x_c, 0, z_c)``, mm.
    semi_axes : ndarray, shape (3,)
        ``(a, b, c)`` along x, y, z, mm.

    Raises
    ------
    ValueError
        When the colony does not lie inside the channel.
    """
    L = float(geometry["length"])
    H = float(geometry["channel_height"])
    W = float(geometry["channel_width"])
    zc = geometry.get("centre_z")
    zc = 0.5 * W if zc is None else float(zc)
    centre = np.array([float(geometry["centre"]), 0.0, zc])
    axes = np.array([0.5 * float(geometry["width"]), float(geometry["height"]),
                     0.5 * float(geometry["depth"])])
    if (centre[0] - axes[0] <= 0 or centre[0] + axes[0] >= L or axes[1] >= H
            or centre[2] - axes[2] <= 0 or centre[2] + axes[2] >= W):
        raise ValueError("geometry: the half-ellipsoid (centre ± width/2, height, "
                         "centre_z ± depth/2) must lie inside the channel")
    return centre, axes


def reference_surface(geometry: dict[str, Any], n: int = 24) -> Any:
    """The colony's undeformed interface without a mesh: the analytic surface,
    triangulated on an (elevation, azimuth) grid (a scanned colony: its height field's
    grid above the floor), for the checks of observed surfaces against the model when a
    study is read (units, placement).

    Parameters
    ----------
    geometry : dict
        Validated ``geometry`` section with ``dim: 3`` (mm).
    n : int
        Elevation rings (the azimuth has ``4 n`` points; the ridge ``4 n`` points along
        its half-ellipse and ``n`` across the width).

    Returns
    -------
    Interface
        Vertices ``(k, 3)`` mm and triangles oriented out of the colony (into the fluid).
    """
    from bayescalib.geometry.interface import Interface

    m = 4 * n
    if geometry["shape"] == "scan":  # the height field the study filled from the scan
        from bayescalib.geometry.surface import surface_above
        from bayescalib.models.fsi.scan3d import HeightField

        hf = HeightField.from_config(geometry["height_field"])
        X, Z = np.meshgrid(hf.x, hf.z, indexing="ij")
        pts = np.column_stack([X.ravel(), np.maximum(hf.heights, 0.0).ravel(), Z.ravel()])
        idx = np.arange(pts.shape[0]).reshape(hf.heights.shape)
        q0, q1, q2, q3 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        tri = np.vstack([np.column_stack([q0.ravel(), q3.ravel(), q1.ravel()]),
                         np.column_stack([q1.ravel(), q3.ravel(), q2.ravel()])])
        p = pts[tri]
        up = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 1] > 0
        tri[~up] = tri[~up][:, ::-1]  # a height field's surface faces up, into the fluid
        grid = Interface.surface(pts, tri.astype(np.int64), name="the model's undeformed colony")
        return surface_above(grid, 1e-9)  # the colony, its rim on the floor
    if geometry["shape"] == "ridge":
        _, lo, hi, b = _outline_face({**geometry, "shape": "half_ellipse"})
        a, xc, W = 0.5 * (hi - lo), 0.5 * (hi + lo), float(geometry["channel_width"])
        t = np.linspace(np.pi, 0.0, m + 1)  # upstream foot to downstream foot
        z = np.linspace(0.0, W, n + 1)
        T, Z = np.meshgrid(t, z, indexing="ij")
        pts = np.column_stack([xc + a * np.cos(T).ravel(), b * np.sin(T).ravel(), Z.ravel()])
        idx = np.arange(pts.shape[0]).reshape(m + 1, n + 1)
        q0, q1, q2, q3 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        tri = np.vstack([np.column_stack([q0.ravel(), q3.ravel(), q1.ravel()]),
                         np.column_stack([q1.ravel(), q3.ravel(), q2.ravel()])])
        mid = pts[tri].mean(axis=1)
        outward = np.column_stack([(mid[:, 0] - xc) / a ** 2, mid[:, 1] / b ** 2,
                                   np.zeros(len(tri))])
    else:
        centre, (a, b, c) = colony_axes(geometry)
        el = np.linspace(0.0, 0.5 * np.pi, n + 1)[:-1]  # rings from the rim up; a pole on top
        az = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
        E, A = np.meshgrid(el, az, indexing="ij")
        ring = np.column_stack([centre[0] + a * np.cos(E).ravel() * np.cos(A).ravel(),
                                b * np.sin(E).ravel(),
                                centre[2] + c * np.cos(E).ravel() * np.sin(A).ravel()])
        pts = np.vstack([ring, [centre[0], b, centre[2]]])
        idx = np.arange(n * m).reshape(n, m)
        nxt = np.roll(idx, -1, axis=1)
        tri = [np.column_stack([idx[:-1].ravel(), idx[1:].ravel(), nxt[:-1].ravel()]),
               np.column_stack([nxt[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel()]),
               np.column_stack([idx[-1], np.full(m, n * m), nxt[-1]])]
        tri = np.vstack(tri)
        outward = (pts[tri].mean(axis=1) - centre) / np.array([a, b, c]) ** 2
    p = pts[tri]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", normal, outward) < 0
    tri[flip] = tri[flip][:, ::-1]
    return Interface.surface(pts, tri.astype(np.int64), name="the model's undeformed colony")


def build_mesh_3d(geometry: dict[str, Any], mesh_cfg: dict[str, Any]) -> BiofilmMesh:
    """Mesh the 3D flow cell.

    Parameters
    ----------
    geometry : dict
        Validated ``geometry`` section with ``dim: 3`` and ``shape: half_ellipse``,
        ``ridge`` or ``scan`` (mm; ``scan``: its ``height_field`` filled when the study
        was read, else the ``scan`` file is read here).
    mesh_cfg : dict
        ``mesh`` section with the preset resolved: ``h_interface``, ``h_solid``,
        ``h_bulk`` (mm), ``grading``, ``curve_order``.

    Returns
    -------
    BiofilmMesh
        ``interface_reference`` (n, 3) mm, ``segments`` the (m, 3) triangles of the
        interface (normals into the fluid), ``patch_height`` = ``b`` (``scan``: the
        height field's largest height).
    """
    import ngsolve as ng
    from netgen.occ import Axes, Box, Ellipsoid, Glue, OCCGeometry, Pnt, X, Y, Z

    if geometry["shape"] not in ("half_ellipse", "ridge", "scan"):
        raise ValueError(f"geometry.shape: the 3D model has the half_ellipse, ridge and scan "
                         f"shapes only, not '{geometry['shape']}'")
    L = float(geometry["length"])
    H = float(geometry["channel_height"])
    W = float(geometry["channel_width"])
    box = Box(Pnt(0, 0, 0), Pnt(L, H, W))
    box.faces.Min(X).name = "inlet"
    box.faces.Max(X).name = "outlet"
    box.faces.Min(Y).name = "floor"
    box.faces.Max(Y).name = "top"
    box.faces.Min(Z).name = "side"
    box.faces.Max(Z).name = "side"
    if geometry["shape"] == "scan":
        from bayescalib.models.fsi.scan3d import (
            HeightField,
            height_field_cutter,
            scan_height_field,
        )

        if geometry.get("height_field"):  # filled when the study was read
            field = HeightField.from_config(geometry["height_field"])
        elif geometry.get("scan"):  # a model built on its own: the scan read here
            field = scan_height_field(geometry, min_gap=float(mesh_cfg["h_interface"]))
        else:
            raise ValueError("geometry.scan is required for shape: scan (the colony's surface "
                             "at zero flow)")
        cutter = height_field_cutter(field, H)
        colony = cutter * box
        b = float(field.heights.max())
    elif geometry["shape"] == "ridge":
        patch, _, _, b = _outline_face({**geometry, "shape": "half_ellipse"})
        colony = patch.Extrude(W * Z)
        colony.faces.name = "interface"
        colony.faces.Min(Z).name = "side"
        colony.faces.Max(Z).name = "side"
        cutter = colony
    else:  # half_ellipse
        centre, (a, b, c) = colony_axes(geometry)
        # netgen's Ellipsoid(axes, r1, r2, r3) puts r1 along n (= Z), r2 along h (= X)
        # and r3 along n x h (= Y): measured on the meshed surface (test_fsi3d)
        cutter = Ellipsoid(Axes(Pnt(*centre), n=Z, h=X), c, a, b)
        cutter.faces.name = "interface"
        colony = cutter * box
    colony.faces.Min(Y).name = "biofilm_floor"
    colony.solids.name = "biofilm"
    fluid = box - cutter
    fluid.solids.name = "fluid"
    shape = Glue([fluid, colony])
    h_if = float(mesh_cfg["h_interface"])
    for f in shape.faces:
        if f.name in ("interface", "biofilm_floor"):
            f.maxh = h_if
    for s in shape.solids:
        if s.name == "biofilm":
            s.maxh = float(mesh_cfg["h_solid"])
    mesh = ng.Mesh(generate_mesh(OCCGeometry(shape), maxh=float(mesh_cfg["h_bulk"]),
                                 grading=float(mesh_cfg["grading"])))
    mesh.Curve(int(mesh_cfg["curve_order"]))
    verts, coords, tris = interface_surface(mesh, "interface", "biofilm")
    return BiofilmMesh(mesh, ["biofilm"], verts, coords, tris, b)


def interface_surface(mesh: Any, boundary: str,
                      solid: str = "biofilm") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangulated interface of a 3D mesh, oriented out of the solid region.

    Parameters
    ----------
    mesh
        NGSolve 3D mesh.
    boundary
        Boundary name of the surface.
    solid
        Region on one side of the surface: each triangle is oriented so that its
        normal points away from the fourth vertex of the ``solid`` tetrahedron it
        bounds (out of the solid, into the fluid), for any shape of the colony.

    Returns
    -------
    vertices : (n,) int
        Mesh vertex numbers of the surface, ascending.
    coords : (n, 3) float
        Their coordinates, mm.
    triangles : (m, 3) int
        Indices into ``coords``; ``(p1 - p0) x (p2 - p0)`` points into the fluid.
    """
    import ngsolve as ng

    tris = [[v.nr for v in el.vertices] for el in mesh.Elements(ng.BND) if el.mat == boundary]
    if not tris:
        raise ValueError(f"mesh has no boundary named '{boundary}'")
    tri = np.array(tris, dtype=int)
    verts, local = np.unique(tri, return_inverse=True)
    local = local.reshape(tri.shape)
    coords = np.array([mesh.vertices[int(v)].point for v in verts], dtype=float)
    opposite: dict[tuple[int, ...], int] = {}  # a solid tetrahedron's face -> its 4th vertex
    for el in mesh.Elements(ng.VOL):
        if el.mat == solid:
            v = [u.nr for u in el.vertices]
            for k in range(4):
                opposite[tuple(sorted(v[:k] + v[k + 1:]))] = v[k]
    try:
        inner = np.array([opposite[tuple(sorted(t))] for t in tri.tolist()], dtype=int)
    except KeyError:
        raise ValueError(f"mesh: the boundary '{boundary}' does not bound the region "
                         f"'{solid}'") from None
    p = coords[local]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    q = np.array([mesh.vertices[int(v)].point for v in inner], dtype=float)
    flip = np.einsum("ij,ij->i", normal, p[:, 0] - q) < 0
    local[flip] = local[flip][:, ::-1]
    return verts, coords, local.astype(np.int64)

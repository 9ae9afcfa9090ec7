"""VTU output of the FSI fields on the deformed mesh (via the ``vtk`` Python package).

The velocity and displacement are quadratic (P2) per element, the pressure linear.
Sampling them at the mesh vertices only would draw a P2 field as its P1 interpolant,
which on a coarse mesh shows as blotches (the field between vertices is lost). The
file therefore holds the mesh refined once at its edge midpoints, and every field is
evaluated element by element at the vertices and edge midpoints (NGSolve
``MapToAllElements``; on a curved mesh the points of the curved element), so that the
piecewise-linear picture interpolates the P2 field at all its nodes:

* 2D: each triangle is split into four (six nodes, ``VTK_TRIANGLE`` cells);
* 3D: each tetrahedron is split into eight (ten nodes, ``VTK_TETRA`` cells): the four
  corner tetrahedra and the inner octahedron cut along one of its diagonals, ordered
  as VTK wants them (positive volume).

Nodes shared by neighbouring elements are merged; on the fluid-biofilm interface the
pressure is the fluid's (it is defined on the fluid only). The dimension is the mesh's.

Point data ``velocity`` (mm/s; in a permeable solid the Darcy velocity), ``pressure``
(Pa; in the solid the pore pressure of a permeable biofilm, else 0), ``displacement``
(mm); 2 components in 2D, 3 in 3D; cell data ``region`` (0 fluid, 1.. solid regions);
points moved by the displacement (in 2D the points have z = 0). The file is written
atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io._atomic_write import atomic_path

#: solver pressure unit (mPa) -> Pa
_PRESSURE_TO_PA = 1.0e-3

#: reference nodes of the triangle: NGSolve's vertices 0, 1, 2 sit at (1, 0), (0, 1),
#: (0, 0); then the midpoints of edges 01, 12, 20
_REF_TRIG = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0), (0.5, 0.5), (0.0, 0.5), (0.5, 0.0)]

#: the four sub-triangles of a triangle, in its six local nodes (vertices 0-2, then
#: the midpoints of edges 01, 12, 20)
_SUBTRIANGLES = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])

#: reference nodes of the tetrahedron: NGSolve's vertices 0, 1, 2, 3 sit at (1, 0, 0),
#: (0, 1, 0), (0, 0, 1), (0, 0, 0); then the midpoints of its edges in NGSolve's order
#: 30, 31, 32, 01, 02, 12 (nodes 4-9; checked in tests/test_fields3d.py)
_REF_TET = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0),
            (0.5, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.5),
            (0.5, 0.5, 0.0), (0.5, 0.0, 0.5), (0.0, 0.5, 0.5)]

#: the eight sub-tetrahedra of a tetrahedron, in its ten local nodes: the corner ones
#: (each the tetrahedron shrunk by 1/2 towards a vertex, so with its orientation), then
#: the octahedron of the midpoints cut along the diagonal m02-m13 (nodes 8 and 5) into
#: four, around the ring m01 (7), m12 (9), m23 (6), m03 (4); all with the parent's
#: orientation
_SUBTETS = np.array([[0, 7, 8, 4], [7, 1, 9, 5], [8, 9, 2, 6], [4, 5, 6, 3],
                     [8, 5, 7, 9], [8, 5, 9, 6], [8, 5, 6, 4], [8, 5, 4, 7]])

_SUBCELLS = {2: (_REF_TRIG, _SUBTRIANGLES), 3: (_REF_TET, _SUBTETS)}


def write_fields_vtu(path: str | Path, solver: Any, pressure_scale: float = _PRESSURE_TO_PA) -> None:
    """Write the current state of ``solver`` (a MonolithicSolver, 2D or 3D) to ``path`` (.vtu)."""
    import ngsolve as ng
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    mesh = solver.mesh
    dim = int(mesh.dim)
    if dim not in _SUBCELLS:
        raise ValueError(f"write_fields_vtu: a {dim}D mesh (2D or 3D only)")
    ref, sub = _SUBCELLS[dim]
    n_nodes, n_sub, n_corner = len(ref), sub.shape[0], sub.shape[1]
    mips = mesh.MapToAllElements(ng.IntegrationRule(points=ref, weights=[0.0] * n_nodes),
                                 ng.VOL)
    coords = (ng.x, ng.y) if dim == 2 else (ng.x, ng.y, ng.z)
    xy = np.asarray(ng.CF(coords)(mips), dtype=float).reshape(-1, dim)
    vel = np.asarray(solver.gfu.components[0](mips), dtype=float).reshape(-1, dim)
    disp = np.zeros_like(xy)
    if solver.i_d is not None:
        disp = np.asarray(solver.gfu.components[solver.i_d](mips), dtype=float).reshape(-1, dim)
    pres = np.zeros(xy.shape[0])
    if solver.i_p is not None:
        pres = np.asarray(solver.gfu.components[solver.i_p](mips), dtype=float).ravel()
        if solver.i_pore is not None:  # pore pressure, zero outside the solid regions
            pres = pres + np.asarray(solver.gfu.components[solver.i_pore](mips),
                                     dtype=float).ravel()
        pres = pres * pressure_scale
    regions = {name: i for i, name in enumerate(mesh.GetMaterials())}
    reg = np.array([regions[el.mat] for el in mesh.Elements(ng.VOL)], dtype=np.int32)
    pts, fields, cells = _merge_nodes(xy, {"velocity": vel, "displacement": disp,
                                           "pressure": pres}, reg, sub)
    vel, disp, pres = fields["velocity"], fields["displacement"], fields["pressure"]
    reg = np.repeat(reg, n_sub)
    if dim == 3:
        cells = _positive_tets(pts, cells)
    pts = pts + disp
    if dim == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    offsets = np.arange(0, n_corner * len(cells) + 1, n_corner, dtype=np.int64)

    grid = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    p.SetData(numpy_to_vtk(pts, deep=True))
    grid.SetPoints(p)
    ca = vtk.vtkCellArray()
    ca.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
               numpy_to_vtkIdTypeArray(np.ascontiguousarray(cells.ravel()), deep=True))
    grid.SetCells(vtk.VTK_TRIANGLE if dim == 2 else vtk.VTK_TETRA, ca)
    for name, arr in (("velocity", vel), ("displacement", disp), ("pressure", pres)):
        va = numpy_to_vtk(np.ascontiguousarray(arr), deep=True)
        va.SetName(name)
        grid.GetPointData().AddArray(va)
    ra = numpy_to_vtk(np.asarray(reg, dtype=np.int32), deep=True)
    ra.SetName("region")
    grid.GetCellData().AddArray(ra)

    with atomic_path(path, suffix=".vtu") as tmp:
        w = vtk.vtkXMLUnstructuredGridWriter()
        w.SetFileName(str(tmp))
        w.SetInputData(grid)
        if not w.Write():
            raise OSError(f"VTK could not write '{path}'")


def _positive_tets(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``tets`` with VTK's orientation: ``(p1 - p0, p2 - p0, p3 - p0)`` right-handed
    (NGSolve's vertex order is the opposite one); nodes 1 and 2 swapped where not."""
    p = points[tets]
    det = np.linalg.det(np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]],
                                 axis=1))
    out = tets.copy()
    flip = det < 0
    out[flip, 1], out[flip, 2] = tets[flip, 2], tets[flip, 1]
    return out


def _merge_nodes(xy: np.ndarray, fields: dict[str, np.ndarray], region: np.ndarray,
                 subcells: np.ndarray = _SUBTRIANGLES
                 ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Merge the element-wise nodes (k per element) that coincide.

    Parameters
    ----------
    xy : (k n_el, d) coordinates of each element's nodes (k = 6 in 2D, 10 in 3D).
    fields : name -> (k n_el,) or (k n_el, d) values at those nodes.
    region : (n_el,) region index (0 fluid): at a node shared by a fluid and a solid
        element the fluid element's value is kept (the pressure is defined there only).
    subcells : (s, c) the sub-cells of an element in its k local nodes.

    Returns
    -------
    points : (p, d) distinct nodes; fields : name -> values at ``points``;
    cells : (s n_el, c) sub-cells in ``points``.
    """
    n_el = region.shape[0]
    k = xy.shape[0] // n_el
    scale = float(np.max(np.abs(xy))) or 1.0
    keys = np.round(xy / (1e-9 * scale)).astype(np.int64)
    # fluid elements first, so that a shared node takes its value from the fluid
    order = np.argsort(region != 0, kind="stable")
    node_order = (k * order[:, None] + np.arange(k)).ravel()
    _, first, inverse = np.unique(keys[node_order], axis=0, return_index=True,
                                  return_inverse=True)
    node_of = np.empty(k * n_el, dtype=np.int64)
    node_of[node_order] = inverse.ravel()
    pick = node_order[first]
    cells = node_of.reshape(n_el, k)[:, subcells].reshape(-1, subcells.shape[1])
    return xy[pick], {kk: v[pick] for kk, v in fields.items()}, cells

"""VTU output of the FSI fields on the deformed mesh (via the ``vtk`` Python package).

The velocity and displacement are quadratic (P2) per element, the pressure linear.
Sampling them at the mesh vertices only would draw a P2 field as its P1 interpolant,
which on a coarse mesh shows as blotches (the field between vertices is lost). The
file therefore holds the mesh refined once: each triangle is split into four at its
edge midpoints, and every field is evaluated element by element at the six nodes
(NGSolve ``MapToAllElements``), so that the piecewise-linear picture interpolates the
P2 field at all its nodes. Nodes shared by neighbouring triangles are merged; on the
fluid-biofilm interface the pressure is the fluid's (it is defined on the fluid only).

Point data ``velocity`` (mm/s; in a permeable solid the Darcy velocity), ``pressure``
(Pa; in the solid the pore pressure of a permeable biofilm, else 0), ``displacement``
(mm); cell data ``region`` (0 fluid, 1.. solid regions); points moved by the
displacement. The file is written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io._atomic_write import atomic_path

#: solver pressure unit (mPa) -> Pa
_PRESSURE_TO_PA = 1.0e-3


def write_fields_vtu(path: str | Path, solver: Any, pressure_scale: float = _PRESSURE_TO_PA) -> None:
    """Write the current state of ``solver`` (a MonolithicSolver) to ``path`` (.vtu)."""
    import ngsolve as ng
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    mesh = solver.mesh
    # reference nodes of the triangle: NGSolve's vertices 0, 1, 2 sit at (1, 0), (0, 1),
    # (0, 0); then the midpoints of edges 01, 12, 20
    ref = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0), (0.5, 0.5), (0.0, 0.5), (0.5, 0.0)]
    mips = mesh.MapToAllElements(ng.IntegrationRule(points=ref, weights=[0.0] * 6), ng.VOL)
    xy = np.asarray(ng.CF((ng.x, ng.y))(mips), dtype=float).reshape(-1, 2)
    vel = np.asarray(solver.gfu.components[0](mips), dtype=float).reshape(-1, 2)
    disp = np.zeros_like(xy)
    if solver.i_d is not None:
        disp = np.asarray(solver.gfu.components[solver.i_d](mips), dtype=float).reshape(-1, 2)
    pres = np.zeros(xy.shape[0])
    if solver.i_p is not None:
        pres = np.asarray(solver.gfu.components[solver.i_p](mips), dtype=float).ravel()
        if solver.i_pore is not None:  # pore pressure, zero outside the solid regions
            pres = pres + np.asarray(solver.gfu.components[solver.i_pore](mips),
                                     dtype=float).ravel()
        pres = pres * pressure_scale
    regions = {name: i for i, name in enumerate(mesh.GetMaterials())}
    reg = np.array([regions[el.mat] for el in mesh.Elements(ng.VOL)], dtype=np.int32)
    pts, fields, tris = _merge_nodes(xy, {"velocity": vel, "displacement": disp,
                                          "pressure": pres}, reg)
    vel, disp, pres = fields["velocity"], fields["displacement"], fields["pressure"]
    reg = np.repeat(reg, 4)
    pts = np.column_stack([pts + disp, np.zeros(len(pts))])
    offsets = np.arange(0, 3 * len(tris) + 1, 3, dtype=np.int64)

    grid = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    p.SetData(numpy_to_vtk(pts, deep=True))
    grid.SetPoints(p)
    ca = vtk.vtkCellArray()
    ca.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
               numpy_to_vtkIdTypeArray(np.ascontiguousarray(tris.ravel()), deep=True))
    grid.SetCells(vtk.VTK_TRIANGLE, ca)
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


#: the four sub-triangles of a triangle, in its six local nodes (vertices 0-2, then
#: the midpoints of edges 01, 12, 20)
_SUBTRIANGLES = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def _merge_nodes(xy: np.ndarray, fields: dict[str, np.ndarray], region: np.ndarray
                 ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Merge the element-wise nodes (6 per element) that coincide.

    Parameters
    ----------
    xy : (6 n_el, 2) reference coordinates of each element's nodes.
    fields : name -> (6 n_el,) or (6 n_el, 2) values at those nodes.
    region : (n_el,) region index (0 fluid): at a node shared by a fluid and a solid
        element the fluid element's value is kept (the pressure is defined there only).

    Returns
    -------
    points : (p, 2) distinct nodes; fields : name -> values at ``points``;
    triangles : (4 n_el, 3) sub-triangles in ``points``.
    """
    n_el = region.shape[0]
    scale = float(np.max(np.abs(xy))) or 1.0
    keys = np.round(xy / (1e-9 * scale)).astype(np.int64)
    # fluid elements first, so that a shared node takes its value from the fluid
    order = np.argsort(region != 0, kind="stable")
    node_order = (6 * order[:, None] + np.arange(6)).ravel()
    _, first, inverse = np.unique(keys[node_order], axis=0, return_index=True,
                                  return_inverse=True)
    node_of = np.empty(6 * n_el, dtype=np.int64)
    node_of[node_order] = inverse.ravel()
    pick = node_order[first]
    tris = node_of.reshape(n_el, 6)[:, _SUBTRIANGLES].reshape(-1, 3)
    return xy[pick], {k: v[pick] for k, v in fields.items()}, tris

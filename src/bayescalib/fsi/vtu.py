"""VTU output of the FSI fields on the deformed mesh (via the ``vtk`` Python package).

Writes the linear (vertex) skeleton of the mesh moved by the displacement, with point
data ``velocity`` (mm/s), ``pressure`` (Pa; 0 in the solid), ``displacement`` (mm) and
cell data ``region`` (0 fluid, 1.. solid regions). Values at vertices are the vertex DOFs
of the hierarchical H1 spaces, i.e. the nodal values. The file is written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayescalib._atomic_write import atomic_path

#: solver pressure unit (mPa) -> Pa
_PRESSURE_TO_PA = 1.0e-3


def write_fields_vtu(path: str | Path, solver: Any, pressure_scale: float = _PRESSURE_TO_PA) -> None:
    """Write the current state of ``solver`` (a MonolithicSolver) to ``path`` (.vtu)."""
    import ngsolve as ng
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    mesh = solver.mesh
    nv = mesh.nv
    xy = np.array([v.point for v in mesh.vertices], dtype=float)
    ub = solver.block(0)
    nu_ = ub.shape[0] // 2
    vel = np.column_stack([ub[:nv], ub[nu_: nu_ + nv]])
    disp = np.zeros((nv, 2))
    if solver.i_d is not None:
        db = solver.block(solver.i_d)
        nd = db.shape[0] // 2
        disp = np.column_stack([db[:nv], db[nd: nd + nv]])
    pres = np.zeros(nv)
    if solver.i_p is not None:
        pgf = solver.gfu.components[solver.i_p]
        # pressure space is defined on the fluid only: evaluate its vertex DOFs via the space
        fes = pgf.space
        pv = pgf.vec.FV().NumPy()
        for v in range(nv):
            dofs = fes.GetDofNrs(ng.NodeId(ng.VERTEX, v))
            if dofs and dofs[0] >= 0:
                pres[v] = pv[dofs[0]] * pressure_scale
    cur = xy + disp
    pts = np.column_stack([cur, np.zeros(nv)])
    regions = {name: i for i, name in enumerate(mesh.GetMaterials())}
    tris = []
    reg = []
    for el in mesh.Elements(ng.VOL):
        tris.append([v.nr for v in el.vertices])
        reg.append(regions[el.mat])
    tris = np.asarray(tris, dtype=np.int64)
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

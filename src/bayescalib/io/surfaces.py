"""Observed 3D interfaces from surface files: STL, PLY, VTK polydata.

:func:`read_surface` reads a triangulated colony surface through ``vtk``'s readers
(``vtkSTLReader`` for ``.stl``, ASCII or binary; ``vtkPLYReader`` for ``.ply``;
``vtkXMLPolyDataReader``/``vtkXMLUnstructuredGridReader`` for ``.vtp``/``.vtu``;
``vtkGenericDataObjectReader`` for legacy ``.vtk``). Polygons and strips are split
into triangles and coincident points merged (``vtkCleanPolyData``: an STL stores each
triangle's corners on their own). The surface then goes through
:func:`bayescalib.geometry.surface.colony_surface`: cut at the floor plane, one
colony, rim on the floor, normals into the fluid.

Units
-----
Surface files carry no unit of their own, so one is required: the ``units`` argument
(``"mm"``, ``"um"`` or ``"m"``), or a unit written in the file's header, found by the
pattern ``unit[s] [=|:] <u>``: in the 80-byte header of a binary STL or the ``solid``
line of an ASCII one, a ``comment`` line of a PLY header, the title line of a legacy
VTK file, or a field-data string array named ``unit`` or ``units`` (VTK XML). Both
given and different is refused; neither given is refused.

Checks (each an :class:`bayescalib.io.observations.ObservationError` naming the file and
the value): missing file, unknown suffix, no or unknown unit, a binary STL whose size
does not match its triangle count (truncated), a VTK header with absurd counts, no
triangles (empty, or lines/points only), NaN/inf coordinates, several separate surfaces
(their number and areas; ``component`` picks one), a rim above the floor (cut off), and
an extent outside an expected ``domain`` (a unit mismatch).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.surface import UNITS, SurfaceError, colony_surface
from bayescalib.io.observations import (
    SURFACE_SUFFIXES,
    ObservationError,
    _as_polydata,
    _validate_vtk_header,
    _vtk_reader,
    validate_domain,
)

__all__ = ["RIM_TOL", "SURFACE_SUFFIXES", "header_units", "read_surface"]

#: a rim vertex this share of the surface's height above the lowest one is still on the
#: floor (a noisy or segmented rim); higher, the colony is cut off
RIM_TOL = 0.02
_UNIT = re.compile(rb"\bunits?\s*[:=]?\s*(mm|um|\xc2\xb5m|m)\b", re.IGNORECASE)


def _binary_stl(head: bytes, size: int) -> bool | None:
    """True for a binary STL of the right size, False for ASCII, None for neither."""
    if len(head) >= 84:
        n = struct.unpack("<I", head[80:84])[0]
        if size == 84 + 50 * n:
            return True
    return False if head.lstrip().lower().startswith(b"solid") else None


def header_units(path: str | Path) -> str | None:
    """The length unit written in a surface file's header (module docstring), or None."""
    p = Path(path)
    suffix = p.suffix.lower()
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    if suffix == ".stl":
        text = head[:80] if _binary_stl(head, p.stat().st_size) else head.split(b"\n", 1)[0]
    elif suffix == ".ply":
        end = head.find(b"end_header")
        lines = head[: end if end >= 0 else len(head)].split(b"\n")
        text = b"\n".join(line for line in lines if line.strip().lower().startswith(b"comment"))
    elif suffix == ".vtk":
        lines = head.split(b"\n", 2)
        text = lines[1] if len(lines) > 1 else b""
    else:
        return None  # XML: field data, read with the file
    m = _UNIT.search(text)
    if not m:
        return None
    u = m.group(1).decode("utf-8").lower()
    return "um" if u == "\u00b5m" else u


def _field_units(data: Any) -> str | None:
    fd = data.GetFieldData()
    for key in ("unit", "units"):
        arr = fd.GetAbstractArray(key) if fd is not None else None
        if arr is not None and arr.GetNumberOfValues() > 0:
            return str(arr.GetValue(0)).strip()
    return None


def _read_polydata(p: Path, where: str):
    import vtk

    suffix = p.suffix.lower()
    if suffix == ".stl":
        with open(p, "rb") as fh:
            head = fh.read(84)
        kind = _binary_stl(head, p.stat().st_size)
        if kind is None:
            n = struct.unpack("<I", head[80:84])[0] if len(head) >= 84 else 0
            raise ObservationError(
                f"{where}: not an STL file: neither ASCII (starting with 'solid') nor binary "
                f"(a binary STL of {n} triangles has {84 + 50 * n} bytes, this file "
                f"{p.stat().st_size}: truncated or corrupt)")
        reader = vtk.vtkSTLReader()
    elif suffix == ".ply":
        reader = vtk.vtkPLYReader()
    else:
        _validate_vtk_header(p, where)
        return _vtk_reader(p)
    reader.SetFileName(str(p))
    reader.Update()
    return reader.GetOutput()


def read_surface(
    path: str | Path,
    *,
    units: str | None = None,
    floor: float | str | None = None,
    component: int | None = None,
    iterations: int = 0,
    rim_tol: float | None = None,
    domain: Sequence[Sequence[float]] | None = None,
) -> tuple[Interface, dict[str, Any]]:
    """A colony's triangulated surface from a file (module docstring).

    Parameters
    ----------
    path : str or Path
        ``.stl`` (ASCII or binary), ``.ply``, ``.vtp``, ``.vtu`` or ``.vtk``.
    units : {"mm", "um", "m"}, optional
        Unit of the coordinates; required unless the header names one.
    floor : float, "auto" or None
        y of the floor plane (in ``units``) below which the surface is cut away (the
        colony's base); ``"auto"``: the lowest point of the surface; None: no cut (the
        surface must be open, its rim on a plane ``y = const``).
    component : int, optional
        Which of several separate surfaces to keep (0 = the largest area).
    iterations : int
        Taubin smoothing iterations (0 = none: a file's surface is taken as it is).
    rim_tol : float, optional
        Largest height of the rim above the floor, in ``units`` (default
        :data:`RIM_TOL` times the surface's height: a file's rim is where a mesher or a
        segmentation put it, within its noise of the floor; a colony cut off by the field
        of view has a rim up to its full height).
    domain : sequence of 3 (min, max), optional
        Expected bounding box in mm (the unit check of
        :func:`bayescalib.io.observations.validate_domain`).

    Returns
    -------
    surface : Interface
        Vertices ``(n, 3)`` in mm and triangles ``(m, 3)``, normals into the fluid.
    info : dict
        ``path``, ``units``, ``units_source`` (``"argument"``/``"header"``), ``points``
        and ``triangles`` read, and the surface's
        (:func:`bayescalib.geometry.surface.colony_surface`).

    Raises
    ------
    ObservationError
        Naming the file and the problem (module docstring).
    """
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    p = Path(path)
    where = str(p)
    suffix = p.suffix.lower()
    if suffix not in SURFACE_SUFFIXES:
        raise ObservationError(f"{where}: unknown surface file type {p.suffix!r}; use one of "
                               f"{', '.join(sorted(SURFACE_SUFFIXES))}")
    if not p.is_file():
        raise ObservationError(f"{where}: no such file")
    if units is not None and units not in UNITS:
        raise ObservationError(f"{where}: unknown units {units!r}; use one of "
                               f"{', '.join(UNITS)}")
    found = header_units(p)
    data = _read_polydata(p, where)
    if found is None and suffix in (".vtp", ".vtu") and isinstance(data, vtk.vtkDataSet):
        found = _field_units(data)
    if found is not None and found not in UNITS:
        raise ObservationError(f"{where}: the header names the unit {found!r}, not one of "
                               f"{', '.join(UNITS)}")
    if units is not None and found is not None and units != found:
        raise ObservationError(f"{where}: units={units!r} but the file's header says "
                               f"{found!r}: which is it? (leave units out to use the header's)")
    u = units or found
    if u is None:
        raise ObservationError(
            f"{where}: no length unit: a surface file has none of its own; pass units= one "
            f"of {', '.join(repr(k) for k in UNITS)} (or write 'unit mm' in its header)")
    f = UNITS[u]
    data = _as_polydata(data, where)
    if not (data.GetNumberOfPolys() or data.GetNumberOfStrips()):
        raise ObservationError(f"{where}: no triangles or polygons (empty, or lines/points "
                               "only): not a surface")
    tri = vtk.vtkTriangleFilter()
    tri.SetInputData(data)
    tri.PassLinesOff()
    tri.PassVertsOff()
    clean = vtk.vtkCleanPolyData()
    clean.SetInputConnection(tri.GetOutputPort())
    clean.Update()
    out = clean.GetOutput()
    pts = vtk_to_numpy(out.GetPoints().GetData()).astype(float) * f
    cells = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).astype(np.int64).reshape(-1, 3)
    if not np.isfinite(pts).all():
        raise ObservationError(f"{where}: NaN/inf point coordinates")
    if floor == "auto":
        floor_mm = float(pts[np.unique(cells), 1].min())
    elif floor is None:
        floor_mm = None
    elif isinstance(floor, str):
        raise ObservationError(f"{where}: floor must be a number, 'auto' or None, got {floor!r}")
    else:
        floor_mm = float(floor) * f
    try:
        tol = RIM_TOL * float(np.ptp(pts[:, 1])) if rim_tol is None else float(rim_tol) * f
        surf, info = colony_surface(pts, cells, floor=floor_mm, component=component,
                                    iterations=iterations, name=where, rim_tol=tol)
    except SurfaceError as exc:
        raise ObservationError(str(exc)) from None
    validate_domain(surf, domain, where, u)
    return surf, {"path": where, "units": u, "units_source": "argument" if units else "header",
                  "points": int(pts.shape[0]), "triangles": int(cells.shape[0]), **info}

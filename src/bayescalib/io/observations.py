"""Observed interfaces: file readers, synthetic data, observation sets.

Sources (all coordinates end up in mm):

* synthetic: a model interface, optionally with Gaussian noise on the node
  coordinates, ``y_obs = y_model + sigma_obs * eps`` (eq:noisy_data), drawn
  from an explicit :class:`numpy.random.Generator` (:func:`add_noise`);
* CSV (``.csv``): an ordered curve, header row naming the columns ``x,y`` (2D;
  extra columns ignored). ``x,y,z`` is accepted when z is constant (a planar
  curve; 3D observations must be surfaces, read from VTK, or with
  :func:`bayescalib.io.surfaces.read_surface` from STL/PLY/VTK with the colony's checks). A last row equal
  to the first closes the curve. Values are in ``units`` (m, mm or um);
* VTK (``.vtp``, ``.vtu``, ``.vtk``, read with the ``vtk`` package): line /
  polyline cells give a 2D polyline (all z equal), polygon / triangle / strip
  cells a 3D triangulated surface. Points not used by any cell are dropped; a
  set of segments forming one path is re-ordered into an ordered curve;
* image (``.png``, ``.tif``, ``.tiff``): a binary mask or a raw greyscale scan
  (e.g. an OCT B-scan) segmented here, read by
  :func:`bayescalib.geometry.imaging.read_mask` and traced by
  :func:`bayescalib.geometry.imaging.mask_contour`. ``pixel_size`` and ``origin``
  (the centre of the bottom-left pixel) are required; ``floor`` may be ``"auto"``.
  :func:`read_interface_info` also returns what the segmentation did (threshold,
  floor found, its positional uncertainty in mm).

Every reader checks its input and raises :class:`ObservationError` naming the
file and the problem: missing file, empty or single-point curve, NaN/inf,
duplicate consecutive points, self-intersecting curve (2D), image without
foreground or background (all black, all white, or a scan whose segmentation finds
no biofilm or no fluid), image larger than
:data:`bayescalib.geometry.imaging.MAX_IMAGE_PIXELS` pixels (refused from its header,
before decoding), and, when an expected ``domain`` (bounding box) is given, an
extent that does not fit it (a typical sign of a unit mismatch, e.g. a curve
2000 units wide in a 2 mm channel read as mm).

Several snapshots (e.g. one per inflow rate) form an :class:`ObservationSet`.
"""

from __future__ import annotations

import csv
import itertools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface, InterfaceError, segment_intersections
from bayescalib.geometry.surface import UNITS  # length unit -> factor to mm
from bayescalib.io._atomic_write import atomic_path

__all__ = [
    "INTERFACE_SUFFIXES",
    "MAX_OBSERVATION_POINTS",
    "MIN_INTERFACE_POINTS",
    "SURFACE_SUFFIXES",
    "UNITS",
    "VOLUME_SUFFIXES",
    "ObservationError",
    "ObservationSet",
    "add_noise",
    "count_points",
    "cut_height",
    "read_interface",
    "read_interface_info",
    "read_points",
    "reader_options",
    "unit_hint",
    "validate_domain",
    "validate_shape",
    "write_interface_csv",
    "write_interface_vtk",
    "write_mask_png",
]


CSV_SUFFIXES = {".csv"}
VTK_SUFFIXES = {".vtp", ".vtu", ".vtk"}
IMAGE_SUFFIXES = {".png", ".tif", ".tiff"}
#: triangulated surfaces (3D): STL, PLY, and VTK files of polygons
SURFACE_SUFFIXES = {".stl", ".ply"} | VTK_SUFFIXES
#: volumes (3D) besides multi-page TIFFs and folders of B-scans: NumPy arrays
VOLUME_SUFFIXES = {".npy"}
#: every suffix of an observed interface file (a folder of B-scans is a volume too)
INTERFACE_SUFFIXES = CSV_SUFFIXES | IMAGE_SUFFIXES | SURFACE_SUFFIXES | VOLUME_SUFFIXES


#: most points an observed interface file may hold (CSV rows, VTK points), counted before
#: the file is read: the study reads every observation file whenever it is read (each
#: start of the workflow), at about 4 us a CSV row (250,000 rows: 1 s on one core), and
#: no measure needs that many (the RKHS measure resolves sigma_W / 4: 1.25 um for the
#: default sigma_W, 800 points per mm of interface)
MAX_OBSERVATION_POINTS = 250_000
#: fewest nodes of an observed interface, not all on one straight line: two points (or
#: points on one line) are a straight segment, no outline of a colony; a study on a
#: two-point file ran all its solves and then failed in its posterior figure (NaN)
MIN_INTERFACE_POINTS = 3


class ObservationError(ValueError):
    """Bad observation input; the message names the file and the problem."""


def unit_hint(ratio: float, units: str, lo: float, hi: float) -> str | None:
    """The length unit (of :data:`UNITS`, other than ``units``) in which a size that is
    ``ratio`` times what is expected when read in ``units`` would be between ``lo`` and
    ``hi`` times it; None when none is. The one rule behind every "the numbers fit if the
    file is in ..." of the unit checks (:func:`validate_domain`,
    :class:`bayescalib.study.Study`)."""
    for u, f in UNITS.items():
        if u != units and units in UNITS and lo <= ratio * f / UNITS[units] <= hi:
            return u
    return None


def count_points(path: str | Path, limit: int = MAX_OBSERVATION_POINTS) -> int | None:
    """The number of points an interface file holds, without reading it: the data rows of
    a CSV (its lines after the first that are neither blank nor comments; counting stops
    once above ``limit``), the largest point count a VTK header declares; None for an
    image (its size is guarded from its header by
    :func:`bayescalib.geometry.imaging.image_size`) or an unknown suffix."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in CSV_SUFFIXES:
        rows, first, tail = 0, True, b""
        with open(p, "rb") as fh:
            while rows <= limit:
                block = fh.read(1 << 20)
                if not block:
                    break
                lines = (tail + block).split(b"\n")
                tail = lines.pop()
                for line in lines:
                    text = line.strip()
                    if not text or text.startswith(b"#") or not text.strip(b", \t\r"):
                        continue
                    if first:
                        first = False  # the header row
                        continue
                    rows += 1
        text = tail.strip()
        if rows <= limit and text and not text.startswith(b"#") and not first:
            rows += 1
        return rows
    if suffix in VTK_SUFFIXES:
        with open(p, "rb") as fh:
            head = fh.read(1 << 20)
        counts = [int(m.group(1) or m.group(2)) for m in _VTK_POINTS.finditer(head)]
        return max(counts) if counts else None
    return None


def validate_shape(interface: Interface, where: str) -> None:
    """Refuse an observed interface with fewer than :data:`MIN_INTERFACE_POINTS` nodes, or
    a 2D curve whose nodes all lie on one straight line (no outline to compare a model's
    with).

    Raises
    ------
    ObservationError
        Naming ``where`` (the file), the number of points and the minimum.
    """
    n = interface.n_points
    why = (f"an observed interface needs at least {MIN_INTERFACE_POINTS} points not all on "
           "one straight line: fewer (or points on one line) are a straight segment, not the "
           "outline of a colony (a study on a two-point file ran all its solves, then failed "
           "drawing its posterior); trace the interface with more points")
    if n < MIN_INTERFACE_POINTS:
        raise ObservationError(f"{where}: the interface has {n} point{'s' if n != 1 else ''}: "
                               + why)
    if interface.dim == 2:
        pts = interface.points - interface.points.mean(axis=0)
        sv = np.linalg.svd(pts, compute_uv=False)
        if sv[0] == 0 or sv[-1] <= 1e-9 * sv[0]:
            raise ObservationError(f"{where}: the {n} points of the interface lie on one "
                                   f"straight line: " + why)


def _unit_factor(units: str, where: str) -> float:
    if units not in UNITS:
        raise ObservationError(f"{where}: unknown units {units!r}; use one of {', '.join(UNITS)}")
    return UNITS[units]


# ---------------------------------------------------------------------------- checks
def _validate_curve_points(pts: np.ndarray, where: str, rows: np.ndarray | None = None) -> None:
    """Empty/single point, NaN/inf and duplicate consecutive points (rows are 1-based file rows)."""
    if pts.shape[0] == 0:
        raise ObservationError(f"{where}: the curve is empty (no points)")
    if pts.shape[0] == 1:
        raise ObservationError(f"{where}: the curve has a single point; at least 2 are needed")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        at = f"row {int(rows[i])}" if rows is not None else f"point {i}"
        raise ObservationError(f"{where}: {int(bad.sum())} point(s) with NaN/inf coordinates (first at {at})")
    dup = np.all(pts[1:] == pts[:-1], axis=1)
    if dup.any():
        i = int(np.flatnonzero(dup)[0]) + 1
        at = f"row {int(rows[i])}" if rows is not None else f"point {i}"
        raise ObservationError(
            f"{where}: duplicate consecutive points ({int(dup.sum())}; first at {at}: {pts[i].tolist()})"
        )


def _validate_simple(curve: Interface, where: str) -> None:
    if curve.dim != 2:
        return
    hits = segment_intersections(curve, max_report=1)
    if hits:
        i, j = hits[0]
        raise ObservationError(
            f"{where}: the curve intersects itself (segments {i} and {j}, near "
            f"{curve.centres[i].round(6).tolist()})" + _order_hint(curve.points))


def _order_hint(pts: np.ndarray) -> str:
    """Words for a curve whose points are not in order along it (a file sorted by another
    column, or unsorted): its consecutive points lie much farther apart (median) than
    each point from its nearest neighbour. Empty otherwise."""
    from scipy.spatial import cKDTree

    if pts.shape[0] < 4:
        return ""
    step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    near = float(np.median(cKDTree(pts).query(pts, k=2)[0][:, 1]))
    if near <= 0 or step < 5.0 * near:
        return ""
    return (f"; its points are not in order along the interface (consecutive points lie "
            f"{step / near:.0f} times farther apart than nearest neighbours, median): a "
            "file's points must follow the interface from one foot to the other")


def validate_domain(interface: Interface, domain: Sequence[Sequence[float]] | None, where: str, units: str = "mm") -> None:
    """Check that the interface fits an expected bounding box (catches unit mismatches).

    Parameters
    ----------
    domain : sequence of (min, max) per axis, mm, optional
        Expected bounding box, e.g. ``[[0, 2], [0, 1]]`` for the 2 mm x 1 mm
        channel. The interface may exceed it by at most half its extent per axis.
    """
    if domain is None:
        return
    dom = np.asarray(domain, dtype=float)
    if dom.shape != (interface.dim, 2) or not np.all(dom[:, 1] > dom[:, 0]):
        raise ObservationError(
            f"{where}: domain must be {interface.dim} pairs (min, max) with max > min, got {dom.tolist()}"
        )
    ext = dom[:, 1] - dom[:, 0]
    lo, hi = interface.bounds
    if np.any(lo < dom[:, 0] - 0.5 * ext) or np.any(hi > dom[:, 1] + 0.5 * ext):
        size = float(np.max(hi - lo))
        ratio = size / float(np.max(ext))
        u = unit_hint(ratio, units, 0.05, 20.0)
        hint = f"; the numbers fit if the file is in {u} (units={u!r})" if u else ""
        if not u and np.all(hi - lo <= 1.5 * ext):  # the size fits, the place does not
            raise ObservationError(
                f"{where}: the interface (box {lo.round(6).tolist()} to "
                f"{hi.round(6).tolist()} mm, read as {units}) lies outside the expected "
                f"domain {dom.tolist()} mm; its size fits the domain but its position does "
                "not: check the file's offset (for an image, its origin, in its units)")
        raise ObservationError(
            f"{where}: interface extent {(hi - lo).round(6).tolist()} mm (box {lo.round(6).tolist()} "
            f"to {hi.round(6).tolist()}) does not fit the expected domain {dom.tolist()} mm; "
            f"unit mismatch? (read as {units}){hint}"
        )


# ---------------------------------------------------------------------------- CSV
def _read_csv_table(path: Path, where: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ObservationError(f"{where}: not a text CSV file") from None
    rows = [r for r in csv.reader(text.splitlines())]
    lines = [(i + 1, r) for i, r in enumerate(rows) if r and any(c.strip() for c in r)]
    lines = [(i, r) for i, r in lines if not r[0].lstrip().startswith("#")]
    if not lines:
        raise ObservationError(f"{where}: the file is empty")
    header = [c.strip().lower() for c in lines[0][1]]
    for sep, name in ((";", "semicolons"), ("\t", "tabs")):
        if len(header) == 1 and sep in header[0]:  # a spreadsheet's export in a locale
            raise ObservationError(
                f"{where}: the columns are separated by {name} (header {lines[0][1][0]!r}): "
                "a CSV file here is comma-separated, with '.' as the decimal point "
                "(header x,y); save it as such (any decimal commas replaced by points, then "
                "the separators by commas)")
    values = []
    rownum = []
    for i, r in lines[1:]:
        if len(r) != len(header):
            raise ObservationError(f"{where}: row {i} has {len(r)} columns, header has {len(header)}")
        try:
            values.append([float(c) for c in r])
        except ValueError:
            raise ObservationError(f"{where}: row {i} has a non-numeric value: {r}") from None
        rownum.append(i)
    arr = np.array(values, dtype=float).reshape(-1, len(header))
    return header, arr, np.array(rownum, dtype=int)


def _columns(header: list[str], wanted: list[str], where: str) -> list[int] | None:
    if all(w in header for w in wanted):
        return [header.index(w) for w in wanted]
    return None


def _read_csv(path: Path, units: str, where: str) -> Interface:
    header, arr, rows = _read_csv_table(path, where)
    cols = _columns(header, ["x", "y", "z"], where) or _columns(header, ["x", "y"], where)
    if cols is None:
        raise ObservationError(
            f"{where}: the header row must name the columns x,y (2D) or x,y,z; got {','.join(header)}"
        )
    pts = arr[:, cols] * _unit_factor(units, where)
    if pts.shape[1] == 3:
        z = pts[:, 2]
        if pts.shape[0] and np.isfinite(z).all() and np.ptp(z) > 1e-12 * max(1.0, float(np.abs(z).max())):
            raise ObservationError(
                f"{where}: a 3D curve (varying z) is not supported; 3D observations must be "
                "triangulated surfaces (VTK)"
            )
        pts = pts[:, :2]
    _validate_curve_points(pts, where, rows)
    closed = pts.shape[0] > 3 and np.array_equal(pts[0], pts[-1])
    if closed:
        pts = pts[:-1]
    try:
        curve = Interface.polyline(pts, closed=closed, name=where)
    except InterfaceError as exc:
        raise ObservationError(str(exc)) from None
    _validate_simple(curve, where)
    return curve


def read_points(path: str | Path, *, units: str = "mm") -> tuple[np.ndarray, np.ndarray | None]:
    """Measurement points (and optional directions) from a CSV file.

    Header ``x,y[,z]`` with optional direction columns ``nx,ny[,nz]``
    (directions are dimensionless; only the coordinates are scaled by ``units``).

    Returns
    -------
    points : ndarray, shape (k, d)
    directions : ndarray, shape (k, d) or None
    """
    p = Path(path)
    where = str(p)
    if not p.is_file():
        raise ObservationError(f"{where}: measurement point file does not exist")
    header, arr, rows = _read_csv_table(p, where)
    cols = _columns(header, ["x", "y", "z"], where) or _columns(header, ["x", "y"], where)
    if cols is None:
        raise ObservationError(f"{where}: the header row must name x,y (or x,y,z); got {','.join(header)}")
    if arr.shape[0] == 0:
        raise ObservationError(f"{where}: no measurement points")
    pts = arr[:, cols] * _unit_factor(units, where)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise ObservationError(f"{where}: NaN/inf in row {int(rows[np.flatnonzero(bad)[0]])}")
    dcols = _columns(header, ["nx", "ny", "nz"][: len(cols)], where)
    dirs = arr[:, dcols] if dcols is not None else None
    if dirs is not None and (not np.isfinite(dirs).all() or np.any(np.linalg.norm(dirs, axis=1) == 0)):
        raise ObservationError(f"{where}: directions must be finite and non-zero")
    return pts, dirs


# ---------------------------------------------------------------------------- VTK
def _vtk_reader(path: Path):
    import vtk

    suffix = path.suffix.lower()
    if suffix == ".vtp":
        reader = vtk.vtkXMLPolyDataReader()
    elif suffix == ".vtu":
        reader = vtk.vtkXMLUnstructuredGridReader()
    else:
        reader = vtk.vtkGenericDataObjectReader()
    reader.SetFileName(str(path))
    reader.Update()
    return reader.GetOutput()


def _order_chain(n: int, seg: np.ndarray) -> np.ndarray | None:
    """Node order of segments forming one simple path or cycle, else None."""
    if seg.shape[0] == 0:
        return None
    deg = np.bincount(seg.ravel(), minlength=n)
    if deg.max() > 2 or np.count_nonzero(deg) != n:
        return None
    adj: dict[int, list[int]] = {i: [] for i in range(n)}
    for a, b in seg:
        adj[int(a)].append(int(b))
        adj[int(b)].append(int(a))
    ends = np.flatnonzero(deg == 1)
    start = int(ends[0]) if ends.size else int(seg[0, 0])
    order = [start]
    prev = -1
    cur = start
    while True:
        nxt = [v for v in adj[cur] if v != prev]
        if not nxt or (nxt[0] == start):
            break
        prev, cur = cur, nxt[0]
        order.append(cur)
    if len(order) != n:
        return None
    # keep the orientation of the first segment as given
    first = seg[0]
    pos = {v: i for i, v in enumerate(order)}
    if ends.size and pos[int(first[0])] > pos[int(first[1])]:
        order = order[::-1]
    if not ends.size and (pos[int(first[1])] - pos[int(first[0])]) % n != 1:
        order = [order[0]] + order[1:][::-1]
    return np.array(order)


#: largest count of points, cells or components a VTK header may declare: VTK allocates
#: what the header says before reading, and a corrupt count aborts the process
#: (std::bad_alloc) or takes minutes; an observed interface is far smaller
MAX_VTK_COUNT = 50_000_000
_VTK_COUNT = re.compile(
    rb'NumberOf(?:Points|Cells|Verts|Lines|Strips|Polys|Components|Tuples)\s*=\s*"\s*(\d+)'
    rb"|^[ \t]*(?:POINTS|VERTICES|LINES|POLYGONS|TRIANGLE_STRIPS|CELLS|CELL_TYPES|OFFSETS"
    rb"|CONNECTIVITY|POINT_DATA|CELL_DATA|DIMENSIONS)[ \t]+(\d+)(?:[ \t]+(\d+))?",
    re.MULTILINE,
)


#: the point counts of a VTK header (XML ``NumberOfPoints="n"``, legacy ``POINTS n``)
_VTK_POINTS = re.compile(rb'NumberOfPoints\s*=\s*"\s*(\d+)|^[ \t]*POINTS[ \t]+(\d+)', re.MULTILINE)


def _validate_vtk_header(path: Path, where: str) -> None:
    """Refuse a VTK file whose header declares absurd sizes (before VTK allocates them)."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 20)
    for m in _VTK_COUNT.finditer(head):
        n = max(int(g) for g in m.groups() if g)
        if n > MAX_VTK_COUNT:
            raise ObservationError(
                f"{where}: the VTK header declares {n} points/cells/components, more than "
                f"{MAX_VTK_COUNT:,}: the file is corrupt (or not an interface)"
            )


def _validate_vtk_cell_ids(data, where: str) -> None:
    """Cells must refer to existing points (VTK filters may crash otherwise)."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    if isinstance(data, vtk.vtkPolyData):
        arrays = [data.GetVerts(), data.GetLines(), data.GetPolys(), data.GetStrips()]
    elif isinstance(data, vtk.vtkUnstructuredGrid):
        arrays = [data.GetCells()]
    else:
        return
    n = data.GetNumberOfPoints()
    for cells in arrays:
        if cells is None or cells.GetNumberOfCells() == 0:
            continue
        conn = vtk_to_numpy(cells.GetConnectivityArray())
        if conn.size and (conn.min() < 0 or conn.max() >= n):
            raise ObservationError(
                f"{where}: cells refer to point ids from {int(conn.min())} to {int(conn.max())} "
                f"but the file has {n} point(s)"
            )


def _as_polydata(data, where: str):
    """A VTK reader's output as polydata, after the checks every VTK-read file gets: points
    present (an unreadable legacy file gives a bare vtkDataObject), cell ids in range."""
    import vtk

    if not isinstance(data, vtk.vtkDataSet) or data.GetNumberOfPoints() == 0:
        raise ObservationError(f"{where}: the VTK file holds no points (empty or unreadable)")
    _validate_vtk_cell_ids(data, where)
    if not isinstance(data, vtk.vtkPolyData):
        geo = vtk.vtkGeometryFilter()
        geo.SetInputData(data)
        geo.Update()
        data = geo.GetOutput()
    return data


def _read_vtk(path: Path, units: str, where: str) -> Interface:
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    _validate_vtk_header(path, where)
    data = _as_polydata(_vtk_reader(path), where)
    if data.GetNumberOfPolys() or data.GetNumberOfStrips():
        tri = vtk.vtkTriangleFilter()
        tri.SetInputData(data)
        tri.PassLinesOff()
        tri.PassVertsOff()
        tri.Update()
        data = tri.GetOutput()
        conn = vtk_to_numpy(data.GetPolys().GetConnectivityArray()).astype(np.int64)
        cells = conn.reshape(-1, 3)
        dim = 3
    elif data.GetNumberOfLines():
        lines = data.GetLines()
        conn = vtk_to_numpy(lines.GetConnectivityArray()).astype(np.int64)
        offs = vtk_to_numpy(lines.GetOffsetsArray()).astype(np.int64)
        segs = []
        for a, b in itertools.pairwise(offs):
            ids = conn[a:b]
            if ids.size >= 2:
                segs.append(np.stack([ids[:-1], ids[1:]], axis=1))
        if not segs:
            raise ObservationError(f"{where}: the VTK lines have fewer than 2 points")
        cells = np.vstack(segs)
        dim = 2
    else:
        raise ObservationError(
            f"{where}: no line, polyline, polygon or triangle cells (a point cloud is not an interface)"
        )
    pts = vtk_to_numpy(data.GetPoints().GetData()).astype(float) * _unit_factor(units, where)
    if not np.isfinite(pts).all():
        raise ObservationError(f"{where}: NaN/inf point coordinates")
    used = np.unique(cells)
    remap = -np.ones(pts.shape[0], dtype=np.int64)
    remap[used] = np.arange(used.size)
    pts, cells = pts[used], remap[cells]
    try:
        if dim == 2:
            z = pts[:, 2]
            if np.ptp(z) > 1e-12 * max(1.0, float(np.abs(pts).max())):
                raise ObservationError(
                    f"{where}: a 3D curve (varying z) is not supported; give a planar curve or a surface"
                )
            pts = pts[:, :2]
            order = _order_chain(pts.shape[0], cells)
            if order is not None:
                closed = cells.shape[0] == pts.shape[0]
                ordered = pts[order]
                _validate_curve_points(ordered, where)
                curve = Interface.polyline(ordered, closed=closed, name=where)
            else:
                curve = Interface(pts, cells, name=where)
            _validate_simple(curve, where)
            return curve
        return Interface.surface(pts, cells, name=where)
    except InterfaceError as exc:
        raise ObservationError(str(exc)) from None


# ---------------------------------------------------------------------------- image
def _one_colony(mask: np.ndarray, s: float, org: Sequence[float], floor_mm: float | None,
                colony: Sequence[float] | None, f: float,
                where: str) -> tuple[np.ndarray, dict[str, Any]]:
    """The mask with the colonies other than the one to trace removed, and the record.

    The colonies are the mask's connected components above the floor (the substrate
    joins them below it) of at least 16 pixels, chosen as for the model's zero-flow scan
    (:func:`bayescalib.geometry.outline.select_colony`): the one with the most pixels in
    the x-range ``colony`` (in the file's units, ``f`` mm per unit), else the largest.
    Specks below 16 pixels are left to the segmentation. Returns the mask and
    ``{"colonies_mm": [[x0, x1], ...] (largest first), "colony_index": k}``."""
    from bayescalib.geometry import outline as ol

    h = mask.shape[0]
    work = mask.copy()
    if floor_mm is not None:
        rows_y = org[1] + (h - 1 - np.arange(h)) * s
        work[rows_y <= floor_mm, :] = False
    cols = None
    if colony is not None:
        lo, hi = (float(v) * f for v in colony)
        cols = ((lo - org[0]) / s, (hi - org[0]) / s)
    try:
        comp, choice = ol.select_colony(work, columns=cols, name=where, refuse_cut=False)
    except ol.OutlineError as exc:
        if colony is not None:
            raise ObservationError(str(exc)) from None
        return mask, {"colonies_mm": [], "colony_index": None}
    ranges = [[org[0] + a * s, org[0] + b * s] for a, b in choice.x_ranges]
    if choice.n_colonies > 1:
        mask = mask & ~(work & ~comp)
    return mask, {"colonies_mm": ranges, "colony_index": int(choice.index)}


def _read_image(path: Path, pixel_size, origin, drop_border: bool, floor, units: str,
                where: str, image: str = "auto",
                segmentation: Mapping[str, Any] | None = None,
                colony: Sequence[float] | None = None) -> tuple[Interface, dict[str, Any]]:
    from bayescalib.geometry import imaging

    if pixel_size is None:
        raise ObservationError(f"{where}: an image needs a pixel size (pixel_size, in {units})")
    if origin is None:
        raise ObservationError(
            f"{where}: an image needs its origin: the position (x, y) of the centre of the "
            f"bottom-left pixel, in {units} (there is no default: (0, 0) would put the image "
            "half a pixel and its whole offset away from the model)")
    f = _unit_factor(units, where)
    org = tuple(float(v) * f for v in origin)
    if len(org) != 2:
        raise ObservationError(f"{where}: origin must be two numbers (x, y), got {origin}")
    if floor is not None and floor != "auto" and isinstance(floor, str):
        raise ObservationError(f"{where}: floor must be a number, 'auto' or null, got {floor!r}")
    try:
        mask, info = imaging.read_mask(path, image=image, segmentation=segmentation)
    except ValueError as exc:  # ImageError, bad settings
        msg = str(exc)
        raise ObservationError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - decoders raise anything on a broken file
        raise ObservationError(
            f"{where}: cannot read the image ({type(exc).__name__}: {exc})"
        ) from None
    s = float(pixel_size) * f
    h = int(mask.shape[0])
    floor_mm = None
    if floor == "auto":
        row = info["floor"]["row"]
        floor_mm = None if row is None else org[1] + (h - 1 - float(row)) * s
    elif floor is not None:
        floor_mm = float(floor) * f
    mask, colonies = _one_colony(mask, s, org, floor_mm, colony, f, where)
    try:
        curve = imaging.mask_contour(mask, s, org, drop_border=drop_border, floor=floor_mm,
                                     name=where)
    except InterfaceError as exc:
        raise ObservationError(str(exc)) from None
    except ValueError as exc:
        msg = str(exc)
        raise ObservationError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    except OSError as exc:
        raise ObservationError(f"{where}: cannot read the image ({exc})") from None
    # the image borders the traced interface runs into (with drop_border, the border's
    # part is not traced: a colony cut there is only a part of it)
    cols = (curve.points[:, 0] - org[0]) / s
    rows = h - 1 - (curve.points[:, 1] - org[1]) / s
    eps = 1e-6
    border = [side for side, hit in (("left", cols.min() <= eps),
                                     ("right", cols.max() >= mask.shape[1] - 1 - eps),
                                     ("top", rows.min() <= eps)) if hit and drop_border]
    mm = {"pixel_size_mm": s, "origin_mm": list(org), "border": border, **colonies,
          "floor_mm": floor_mm, "floor_source": "auto" if floor == "auto" else
          ("given" if floor is not None else "none"),
          "sigma_mm": None if info["sigma_px"] is None else float(info["sigma_px"]) * s,
          "sigma_noise_mm": None if info["sigma_noise_px"] is None
          else float(info["sigma_noise_px"]) * s}
    return curve, {**info, **mm}


def image_substrate_offset(info: Mapping[str, Any], *, units: str,
                           origin: Sequence[float]) -> str | None:
    """Why an observed image's substrate is not on the flow cell's floor y = 0, or None.

    With ``floor: auto`` the reading finds the substrate (a bright band's top edge, a
    full-width band, or the foreground's bottom); more than 10 um (and two pixels)
    from y = 0 is a wrong ``origin``: the traced interface would stand that far above
    (or below) the model's, whose feet are on y = 0, and the placement check lets it
    through up to a quarter of the colony's height (33 um on the OCT example, 16 sigma_N,
    was read without a word). As :func:`bayescalib.io.volumes.substrate_offset` for
    volumes and the zero-flow scan's check (:mod:`bayescalib.io.colony`). A floor given
    as a number is the user's plane: None.

    Parameters
    ----------
    info : mapping
        The reading record of :func:`read_interface_info` for an image.
    units, origin
        As given (the origin that fits is written in them).
    """
    from bayescalib.io.colony import FLOOR_TOL_MM

    fl = info.get("floor") or {}
    if info.get("floor_source") != "auto" or info.get("floor_mm") is None:
        return None
    s = float(info["pixel_size_mm"])
    y_sub = float(info["floor_mm"])
    band = fl.get("edge_row") is not None and fl.get("row") is not None
    if band:  # the band's own top edge, below the halo the trace is cut above
        y_sub += (float(fl["row"]) - float(fl["edge_row"])) * s
    tol = max(FLOOR_TOL_MM, 2.0 * s)
    if abs(y_sub) <= tol:
        return None
    f = _unit_factor(units, "origin")
    fixed = f"{float(origin[0]):.6g}, {float(origin[1]) - y_sub / f:.6g}"
    what = ("the substrate's surface (the top edge of the bright band found below the "
            "colony)" if band else f"the floor found ({fl.get('method')})")
    return (f"{what} lies at y = {y_sub * 1e3:.3g} um in the flow cell (origin "
            f"{[float(v) for v in origin]} {units}), but the flow cell's floor is y = 0 "
            f"(tolerance {tol * 1e3:.3g} um): the observed interface would stand "
            f"{abs(y_sub) * 1e3:.3g} um {'above' if y_sub > 0 else 'below'} the model's. With "
            f"origin [{fixed}] {units} it would lie there (origin is the centre of the "
            "bottom-left pixel)")


# ---------------------------------------------------------------------------- API
#: the keys of an ``observations.files`` entry that are :func:`read_interface`'s options
READER_KEYS = ("units", "pixel_size", "origin", "drop_border", "floor", "image",
               "segmentation", "component", "colony")


def reader_options(entry: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`read_interface` for one ``observations.files``
    entry (or ``observations.reference``): the keys given, none of the unset ones."""
    return {k: entry[k] for k in READER_KEYS if entry.get(k) is not None}


def cut_height(interface: Interface, info: Mapping[str, Any] | None) -> float | None:
    """The height y (mm) of the plane a 3D observed surface was cut at above the flow
    cell's floor y = 0, from its reading record (:func:`read_interface_info`): a volume's
    floor (found on top of the bright substrate's halo, or given), a surface file's
    given floor; None for a 2D interface, a surface not cut above the floor, or no record
    (synthetic data). The model is compared above the same plane, since the observation
    holds nothing of the colony below it."""
    y = None
    if interface.dim == 3 and info:
        y = info["floor"]["y_mm"] if info.get("kind") == "volume" else info.get("floor_mm")
    return float(y) if y is not None and float(y) > 0.0 else None


def read_interface(
    path: str | Path,
    *,
    units: str = "mm",
    pixel_size: float | None = None,
    origin: Sequence[float] | None = None,
    drop_border: bool = True,
    floor: float | str | None = None,
    image: str = "auto",
    segmentation: Mapping[str, Any] | None = None,
    domain: Sequence[Sequence[float]] | None = None,
    component: int | None = None,
    colony: Sequence[float] | None = None,
) -> Interface:
    """Read an interface from CSV, VTK, an image (mask or raw scan), a surface file or a
    volume, in mm.

    Parameters
    ----------
    path : str or Path
        2D: ``.csv``, ``.vtp``/``.vtu``/``.vtk`` (lines), ``.png``/``.tif``/``.tiff``
        (one page). 3D: a surface (``.stl``, ``.ply``, or VTK polygons;
        :func:`bayescalib.io.surfaces.read_surface`) or a volume (a folder of B-scans,
        ``.npy``, a multi-page TIFF; :mod:`bayescalib.io.volumes`).
    units : {"mm", "m", "um"}
        Units of the coordinates in the file (and of ``pixel_size``/``origin``). A
        surface file whose header names another unit is refused.
    pixel_size : float or (float, float, float), optional
        Image pixel size (required for images); a volume's voxel size (dx, dy, dz).
    origin : (float, float) or (float, float, float), optional
        Image: position of the centre of the bottom-left pixel (required for images);
        a volume's: of the first B-scan's bottom-left pixel, (x, y, z).
    drop_border : bool
        Image: drop the boundary along the image border/floor (see
        :mod:`bayescalib.geometry.imaging`).
    floor : float or "auto", optional
        Image: y of the floor (in ``units``), or ``"auto"`` (found in the image,
        :func:`bayescalib.geometry.imaging.find_floor`); the contour part on it is dropped.
    image : {"auto", "mask", "scan"}
        Image: a binary mask or a raw scan to segment (auto: two grey values = mask).
    segmentation : mapping, optional
        Image: segmentation settings of a scan (``smooth``, ``threshold``, ``min_size``).
    domain : sequence of (min, max) per axis in mm, optional
        Expected bounding box; an interface that does not fit raises (unit check).
    component : int, optional
        Volume or surface: which colony when there are several (0 = the largest).
    colony : (float, float), optional
        2D image: an x-range in ``units`` choosing the colony to trace when the image
        holds several (the one with the most pixels in it); None: the largest.

    Raises
    ------
    ObservationError
        Naming the file and the problem.
    """
    return read_interface_info(path, units=units, pixel_size=pixel_size, origin=origin,
                               drop_border=drop_border, floor=floor, image=image,
                               segmentation=segmentation, domain=domain,
                               component=component, colony=colony)[0]


def read_interface_info(
    path: str | Path,
    *,
    units: str = "mm",
    pixel_size: float | None = None,
    origin: Sequence[float] | None = None,
    drop_border: bool = True,
    floor: float | str | None = None,
    image: str = "auto",
    segmentation: Mapping[str, Any] | None = None,
    domain: Sequence[Sequence[float]] | None = None,
    component: int | None = None,
    colony: Sequence[float] | None = None,
) -> tuple[Interface, dict[str, Any]]:
    """:func:`read_interface`, plus what was done to get it.

    Returns
    -------
    interface : Interface
    info : dict
        ``{"kind": "csv"}`` or ``{"kind": "vtk"}`` for coordinate files (2D);
        ``kind`` ``"surface"`` with :func:`bayescalib.io.surfaces.read_surface`'s info
        for a surface, ``"volume"`` with
        :func:`bayescalib.io.volumes.read_volume_surface`'s for a volume; for images
        the dict of :func:`bayescalib.geometry.imaging.read_mask` (``kind`` "mask" or
        "scan", threshold, floor found, segmentation uncertainty in pixels) plus
        ``pixel_size_mm``, ``origin_mm``, ``floor_mm`` (the floor cut at, None: none),
        ``floor_source`` ("auto", "given", "none"), ``border`` (the image sides, of
        "left", "right", "top", that the traced interface runs into), ``colonies_mm``
        (the x-ranges [x0, x1] of the image's colonies, mm, largest first),
        ``colony_index`` (the traced one's rank in that list), ``sigma_mm`` and
        ``sigma_noise_mm``
        (the segmentation's positional uncertainty of the interface, mm; None for masks).
    """
    from bayescalib.io.surfaces import read_surface
    from bayescalib.io.volumes import is_volume, read_volume_surface

    p = Path(path)
    where = str(p)
    if not p.exists():
        raise ObservationError(f"{where}: file does not exist")
    suffix = p.suffix.lower()
    _unit_factor(units, where)
    volume = is_volume(p)
    if not p.is_file() and not volume:
        raise ObservationError(f"{where}: not a file")
    surface = suffix in SURFACE_SUFFIXES - VTK_SUFFIXES
    if suffix in VTK_SUFFIXES:  # VTK: a 2D curve (lines) or a surface (polygons)
        surface = _read_vtk(p, units, where).dim == 3
    if component is not None and not (surface or volume):
        raise ObservationError(f"{where}: component picks a colony of a volume or a surface "
                               "(3D); a 2D interface has none")
    if colony is not None and suffix not in IMAGE_SUFFIXES:
        raise ObservationError(f"{where}: colony (an x-range choosing one of several colonies) "
                               "applies to 2D images; use component for a volume or a surface")
    info: dict[str, Any]
    if volume:
        iface, info = read_volume_surface(
            p, units=units, pixel_size=pixel_size, origin=origin, image=image,
            segmentation=segmentation, floor="auto" if floor is None else floor,
            component=component)
    elif surface:
        iface, sinfo = read_surface(p, units=units, floor=floor, component=component)
        info = {"kind": "surface", **sinfo}
    elif suffix in CSV_SUFFIXES:
        iface, info = _read_csv(p, units, where), {"kind": "csv"}
    elif suffix in VTK_SUFFIXES:
        iface, info = _read_vtk(p, units, where), {"kind": "vtk"}
    elif suffix in IMAGE_SUFFIXES:
        iface, info = _read_image(p, pixel_size, origin, drop_border, floor, units, where,
                                  image=image, segmentation=segmentation, colony=colony)
    else:
        known = sorted(INTERFACE_SUFFIXES)
        raise ObservationError(f"{where}: unknown interface file type {suffix!r}; use one of "
                               f"{', '.join(known)} (or a folder of B-scans: a volume)")
    validate_domain(iface, domain, where, units)
    return iface, info


def write_interface_csv(path: str | Path, interface: Interface) -> None:
    """Write an ordered 2D curve as CSV (header ``x,y``, mm, full precision).

    A closed curve is written with its first point repeated at the end, which
    :func:`read_interface` reads back as closed.
    """
    p = Path(path)
    if interface.dim != 2 or not interface.is_chain():
        raise ObservationError(f"{p}: CSV holds ordered 2D curves only; write surfaces as VTK (.vtp)")
    pts = interface.points
    if interface.n_cells == interface.n_points:
        pts = np.vstack([pts, pts[:1]])
    with atomic_path(p, suffix=".csv") as tmp, tmp.open("w", newline="") as fh:
        fh.write("x,y\n")
        for x, y in pts:
            fh.write(f"{float(x)!r},{float(y)!r}\n")


def write_interface_vtk(path: str | Path, interface: Interface) -> None:
    """Write an interface as VTK XML PolyData (``.vtp``): lines in 2D (z = 0), triangles in 3D."""
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    p = Path(path)
    pts = interface.points
    if interface.dim == 2:
        pts = np.column_stack([pts, np.zeros(pts.shape[0])])
    vpts = vtk.vtkPoints()
    vpts.SetData(numpy_to_vtk(np.ascontiguousarray(pts), deep=True))
    m, k = interface.cells.shape
    offsets = np.arange(0, (m + 1) * k, k, dtype=np.int64)
    arr = vtk.vtkCellArray()
    arr.SetData(
        numpy_to_vtkIdTypeArray(offsets, deep=True),
        numpy_to_vtkIdTypeArray(np.ascontiguousarray(interface.cells.ravel()), deep=True),
    )
    poly = vtk.vtkPolyData()
    poly.SetPoints(vpts)
    if interface.dim == 2:
        poly.SetLines(arr)
    else:
        poly.SetPolys(arr)
    writer = vtk.vtkXMLPolyDataWriter()
    writer.SetFileName(str(p))
    writer.SetInputData(poly)
    if not writer.Write():
        raise OSError(f"{p}: writing the VTK file failed")


def write_mask_png(
    path: str | Path,
    mask: np.ndarray,
    *,
    pixel_size: float,
    origin: Sequence[float],
    units: str = "mm",
    metadata: dict | None = None,
) -> Path:
    """Write a segmented image (8-bit PNG, biofilm 255, fluid 0) and its sidecar.

    The sidecar ``<path>.json`` (e.g. ``mask.png.json``) holds what is needed to read
    the mask back (``pixel_size``, ``origin`` of the centre of the bottom-left pixel,
    ``units``; the convention of :mod:`bayescalib.geometry.imaging`) plus free
    ``metadata`` (e.g. how it was rendered). The reader takes ``pixel_size`` and
    ``origin`` from the observation config, not from the sidecar.

    Returns
    -------
    Path
        The sidecar's path.
    """
    import json

    from skimage import io

    p = Path(path)
    m = np.asarray(mask, dtype=bool)
    if p.suffix.lower() != ".png":
        raise ObservationError(f"{p}: a mask is written as .png")
    if m.ndim != 2:
        raise ObservationError(f"{p}: a mask must be 2D, got shape {m.shape}")
    f = _unit_factor(units, str(p))
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise ObservationError(f"{p}: pixel_size must be > 0 {units}, got {pixel_size}")
    if len(origin) != 2:
        raise ObservationError(f"{p}: origin must be two numbers (x, y), got {origin}")
    with atomic_path(p, suffix=".png") as tmp:
        io.imsave(tmp, (m * 255).astype(np.uint8), check_contrast=False)
    side = p.with_name(p.name + ".json")
    info = {"pixel_size": float(pixel_size), "origin": [float(v) for v in origin], "units": units,
            "shape": list(m.shape), "foreground": "biofilm = 255",
            "convention": "pixel (row, col) centre at x = x0 + col*s, y = y0 + (H-1-row)*s",
            "pixel_size_mm": float(pixel_size) * f, **(metadata or {})}
    with atomic_path(side, suffix=".json") as tmp:
        tmp.write_text(json.dumps(info, indent=2) + "\n")
    return side


def add_noise(interface: Interface, sigma_obs: float, rng: np.random.Generator) -> Interface:
    """Synthetic observation with Gaussian coordinate noise (eq:noisy_data).

    Parameters
    ----------
    interface : Interface
        Model interface (mm).
    sigma_obs : float
        Noise standard deviation in mm (>= 0; 0 returns the interface unchanged).
    rng : numpy.random.Generator
        Source of randomness (pass a seeded generator for reproducibility).

    Returns
    -------
    Interface
        Same cells, points ``+ sigma_obs * N(0, I)``.
    """
    if not (np.isfinite(sigma_obs) and sigma_obs >= 0):
        raise ObservationError(f"sigma_obs must be >= 0 mm, got {sigma_obs}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    if sigma_obs == 0:
        return interface
    noisy = interface.points + sigma_obs * rng.standard_normal(interface.points.shape)
    return Interface(noisy, interface.cells, name=f"{interface.name} + noise({sigma_obs} mm)")


@dataclass
class ObservationSet:
    """Observed snapshots of one experiment (e.g. one per inflow rate).

    Attributes
    ----------
    snapshots : list of Interface
    labels : list of str
        One unique label per snapshot.
    loads : list of float, optional
        The load/inflow rate of each snapshot (e.g. mm^2/s), when known.
    """

    snapshots: list[Interface]
    labels: list[str] = field(default_factory=list)
    loads: list[float] | None = None

    def __post_init__(self) -> None:
        self.snapshots = list(self.snapshots)
        if not self.snapshots:
            raise ObservationError("an observation set needs at least one snapshot")
        if not all(isinstance(s, Interface) for s in self.snapshots):
            raise ObservationError("observation snapshots must be Interface objects")
        if not self.labels:
            self.labels = [f"snapshot{i}" for i in range(len(self.snapshots))]
        self.labels = [str(x) for x in self.labels]
        if len(self.labels) != len(self.snapshots):
            raise ObservationError(
                f"{len(self.labels)} label(s) for {len(self.snapshots)} snapshot(s)"
            )
        if len(set(self.labels)) != len(self.labels):
            raise ObservationError(f"snapshot labels must be unique, got {self.labels}")
        if self.loads is not None:
            self.loads = [float(v) for v in self.loads]
            if len(self.loads) != len(self.snapshots):
                raise ObservationError(f"{len(self.loads)} load(s) for {len(self.snapshots)} snapshot(s)")
        dims = {s.dim for s in self.snapshots}
        if len(dims) != 1:
            raise ObservationError("all snapshots of an observation set must have the same dimension")

    def __len__(self) -> int:
        return len(self.snapshots)

    @classmethod
    def from_files(
        cls,
        paths: Sequence[str | Path],
        labels: Sequence[str] | None = None,
        loads: Sequence[float] | None = None,
        **read_options,
    ) -> ObservationSet:
        """Read one snapshot per file with :func:`read_interface` (labels default to file stems)."""
        snaps = [read_interface(p, **read_options) for p in paths]
        labs = list(labels) if labels else [Path(p).stem for p in paths]
        return cls(snaps, labs, list(loads) if loads is not None else None)

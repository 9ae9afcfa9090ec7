"""Flow-cell geometry and mesh of the biofilm problem (paper Sec. 4.1, App. B).

Domain: a channel ``[0, L] x [0, H]`` (default 2 mm x 1 mm, lengths in mm) with a
biofilm patch attached to the floor. Shapes:

* ``half_ellipse`` — the upper half of an ellipse with semi-axes ``width/2`` and
  ``height`` centred at ``(centre, 0)`` (exact OpenCascade ellipse; default
  0.6 mm wide, 0.4 mm high at x = 1 mm);
* ``polyline`` — an arbitrary closed outline ``[[x, y], ...]`` in mm, in either
  orientation (it is made counterclockwise: OpenCascade triangulates no face whose
  wire runs clockwise); the part below the floor ``y = 0`` is cut off, so the outline
  may start and end on or below the floor; every point is a mesh vertex;
* ``scan`` — the colony of a recording at zero flow (``geometry.scan``: a mask, a raw
  B-scan or an outline file; :mod:`bayescalib.io.colony`): its interface, smoothed at
  a stated length, is one spline edge from foot to foot, so the observed zero-flow
  interface is the model's reference by construction.

Heterogeneous split (6-parameter case, paper Sec. 4.5): with
``subdomains.enabled`` the biofilm is cut by two horizontal lines at
``y = cuts[0] * h`` and ``y = cuts[1] * h`` (``h`` = patch height) into

* ``base``   — ``0 <= y < cuts[0] h``, attached to the floor (the stiff one),
* ``middle`` — ``cuts[0] h <= y < cuts[1] h`` (the largest),
* ``cap``    — ``y >= cuts[1] h``.

With the default cuts (0.2, 0.75) the half-ellipse splits into about 25 %, 61 % and
14 % of its area, which makes ``middle`` the largest as in the paper.

The channel is a truncated piece of the flow cell: a parabolic inflow is imposed at the
inlet and the outflow is free. A colony disturbs the flow over about a channel height
up- and downstream, so a colony whose foot lies nearer an end deforms differently from
the same colony in the long flow cell; :data:`END_EFFECT` holds how much, measured, and
the study's reading refuses a colony too near the inlet and notes one nearer than
:data:`NOTE_CLEARANCE` channel heights to an end (:func:`channel_ends`, :func:`end_effect`).

Boundary names: ``inlet`` (x = 0), ``outlet`` (x = L), ``top``, ``floor`` (fluid part of
the floor), ``biofilm_floor`` (the clamped biofilm base), ``interface`` (fluid–biofilm)
and ``cut`` (inner boundaries between biofilm subdomains). Region names: ``fluid`` and
``biofilm`` or ``base|middle|cap``. The mesh is graded from ``h_interface`` on the
interface (and the biofilm base and cuts) to ``h_solid`` inside the biofilm and
``h_bulk`` elsewhere, and curved with ``curve_order`` (``mesh.Curve``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

SOLID_SUBDOMAINS = ("base", "middle", "cap")


@dataclass
class BiofilmMesh:
    """A meshed flow cell.

    Attributes
    ----------
    mesh
        The NGSolve mesh (lengths in mm).
    solid_regions
        Names of the solid material regions (``["biofilm"]`` or ``["base", "middle", "cap"]``).
    interface_vertices
        (n,) vertex numbers of the interface, ordered from the upstream foot to the
        downstream foot.
    interface_reference
        (n, 2) coordinates of these vertices in mm.
    segments
        (n - 1, 2) consecutive index pairs into the interface arrays.
    patch_height
        Height of the biofilm patch in mm.
    """

    mesh: Any
    solid_regions: list[str]
    interface_vertices: np.ndarray
    interface_reference: np.ndarray
    segments: np.ndarray
    patch_height: float


#: The RMS change of a colony's interface displacement against the same colony in a
#: long channel, by the clearance c of its upstream foot from the inlet (or of its
#: downstream foot from the outlet) over the channel height H: pairs (c / H, change /
#: RMS displacement). Measured with ``benchmarks/channel_clearance.py`` on the colony of
#: ``examples/oct_colony`` (E 400 Pa, nu 0.3, 100 mm^2/s, coarse mesh, H = 1 mm); the
#: paper mesh and a channel of H = 2 mm give the same inlet figures within 1-3 points
#: (``docs/channel_ends.md``), so they are read as a function of
#: c / H. The outlet's last figure is the mesh's own difference between channel lengths.
END_EFFECT: dict[str, tuple[tuple[float, float], ...]] = {
    "inlet": ((0.15, 1.285), (0.2, 0.938), (0.3, 0.538), (0.5, 0.212), (0.75, 0.079),
              (1.0, 0.037), (1.5, 0.006)),
    "outlet": ((0.1, 0.109), (0.2, 0.100), (0.3, 0.097), (0.5, 0.082), (0.75, 0.052),
               (1.0, 0.023), (1.5, 0.016)),
}
#: The nearest clearance of the upstream foot from the inlet a study may have, in channel
#: heights: the displacement is then off by half (:data:`END_EFFECT`), and at 0.1 the
#: solves fail (inverted elements on the coarse and the paper mesh, measured)
MIN_INLET_CLEARANCE = 0.3
#: Below this clearance of either foot from its end, in channel heights, a study of
#: observed files is told how much the truncated channel changes the deformation
NOTE_CLEARANCE = 1.0
#: The clearance, in channel heights, that the notes advise (the change below 2 %)
ADVISED_CLEARANCE = 1.5


def channel_ends(geometry: dict[str, Any]) -> tuple[float, float]:
    """The colony's clearances from the channel's ends.

    Parameters
    ----------
    geometry : dict
        Validated 2D ``geometry`` section (mm; ``shape: scan`` with its outline filled).

    Returns
    -------
    (float, float)
        Distance of the upstream foot from the inlet (x = 0) and of the downstream foot
        from the outlet (x = ``length``), mm; negative where the colony reaches past.
    """
    x = reference_interface(geometry)[:, 0]
    return float(x.min()), float(geometry["length"]) - float(x.max())


def end_effect(clearance: float, end: str) -> float:
    """The measured change of the colony's displacement from the channel's end.

    Parameters
    ----------
    clearance : float
        Distance of the colony's foot from the end, in channel heights (c / H).
    end : {"inlet", "outlet"}

    Returns
    -------
    float
        RMS change of the interface displacement against a long channel, relative to its
        RMS (:data:`END_EFFECT`, log-linear between the measured clearances, held at
        the first and last one beyond them).
    """
    c, e = np.array(END_EFFECT[end]).T
    return float(np.exp(np.interp(clearance, c, np.log(e))))


#: whether Netgen has generated a mesh in this process, or in the process it was forked
#: from (the flag is inherited by a fork): a process forked after that hangs in its own
#: mesh generation (NGSolve 6.2.2608), so the solve path then starts its solve processes
#: afresh (:func:`bayescalib.models.forward.solve_points`)
MESHED = False


def generate_mesh(geo, **options):
    """``geo.GenerateMesh(**options)``, recorded in :data:`MESHED`."""
    global MESHED
    MESHED = True
    return geo.GenerateMesh(**options)


def _outline_face(geometry: dict[str, Any]):
    """OpenCascade face of the biofilm patch above the floor, and its height (mm)."""
    from netgen.occ import Ellipse, Face, Wire, WorkPlane, gp_Ax2d, gp_Dir2d, gp_Pnt2d

    L = float(geometry["length"])
    if geometry["shape"] == "half_ellipse":
        a = 0.5 * float(geometry["width"])
        b = float(geometry["height"])
        xc = float(geometry["centre"])
        if xc - a <= 0 or xc + a >= L or b >= float(geometry["channel_height"]):
            raise ValueError(
                "geometry: the half-ellipse (centre ± width/2, height) must lie inside the channel"
            )
        major, minor, axis = (b, a, gp_Dir2d(0, 1)) if b >= a else (a, b, gp_Dir2d(1, 0))
        full = Face(Wire([Ellipse(gp_Ax2d(gp_Pnt2d(xc, 0), axis), major, minor).Edge()]))
        lo, hi = xc - a, xc + a
    elif geometry["shape"] == "polyline":
        from bayescalib.geometry.outline import OutlineError, counterclockwise

        pts = np.asarray(geometry["outline"], dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
            raise ValueError("geometry.outline: need at least 3 points [x, y] (mm)")
        try:  # OpenCascade triangulates no face whose wire runs clockwise
            pts = counterclockwise(pts)
        except OutlineError as exc:
            raise ValueError(f"geometry.outline: {exc}") from None
        wp = WorkPlane().MoveTo(*pts[0])
        for p in pts[1:]:
            wp.LineTo(*p)
        full = wp.Close().Face()
        lo, hi = float(pts[:, 0].min()), float(pts[:, 0].max())
        b = float(pts[:, 1].max())
        if lo <= 0 or hi >= L or b >= float(geometry["channel_height"]) or b <= 0:
            raise ValueError("geometry.outline must lie inside the channel, above the floor")
        if pts[:, 1].min() > 1e-12:
            raise ValueError("geometry.outline must reach the floor (some points with y <= 0)")
    elif geometry["shape"] == "scan":
        full, lo, hi, b = _scan_face(scan_interface(geometry))
        if lo <= 0 or hi >= L or b >= float(geometry["channel_height"]):
            raise ValueError(f"geometry.scan: the colony (x = {lo:.4g} to {hi:.4g} mm, "
                             f"{b:.4g} mm high) must lie inside the channel")
    else:
        raise ValueError(f"geometry.shape: unknown shape '{geometry['shape']}'")
    below = WorkPlane().MoveTo(lo - 1.0, -10.0).Rectangle(hi - lo + 2.0, 10.0).Face()
    patch = full - below
    return patch, lo, hi, b


def scan_interface(geometry: dict[str, Any]) -> np.ndarray:
    """The undeformed interface of ``shape: scan`` (mm, foot to foot).

    A study fills ``geometry.outline`` with it when it is read (so the solves depend
    on the points, not on the file's name); a config used on its own (the CLI) reads
    ``geometry.scan`` here.
    """
    if geometry.get("outline"):
        return np.asarray(geometry["outline"], dtype=float)
    from bayescalib.io.colony import read_colony

    if not geometry.get("scan"):
        raise ValueError("geometry.scan is required for shape: scan (the zero-flow recording)")
    return read_colony(geometry["scan"], where="geometry.scan").interface


def reference_interface(geometry: dict[str, Any], n: int = 200) -> np.ndarray:
    """The model's undeformed interface from the geometry section alone (no mesh).

    Parameters
    ----------
    geometry : dict
        Validated ``geometry`` section (mm); for ``shape: scan`` with its outline
        filled (or the scan readable).
    n : int
        Points of the half-ellipse.

    Returns
    -------
    ndarray, shape (m, 2)
        From the upstream foot to the downstream foot, mm (what the mesh's interface
        approximates).
    """
    from bayescalib.geometry.outline import counterclockwise, interface_above_floor

    shape = geometry["shape"]
    if shape == "half_ellipse":
        t = np.linspace(np.pi, 0.0, n)
        a, b, xc = 0.5 * float(geometry["width"]), float(geometry["height"]), float(geometry["centre"])
        return np.column_stack([xc + a * np.cos(t), b * np.sin(t)])
    if shape == "polyline":
        return interface_above_floor(counterclockwise(np.asarray(geometry["outline"], dtype=float)),
                                     floor=0.0, closed=True)
    return scan_interface(geometry)


def _scan_face(interface: np.ndarray):
    """OpenCascade face of a colony whose interface (foot to foot, mm) came from a scan.

    The interface is one spline edge through the points (no mesh vertex at every
    traced point); its two ends are moved just below the floor and joined by a
    rectangle below it, so the cut at y = 0 places the feet where the spline
    crosses the floor. The wire runs counterclockwise (see :func:`counterclockwise`).
    """
    from netgen.occ import WorkPlane, gp_Pnt2d

    p = np.asarray(interface, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 4:
        raise ValueError("geometry.outline: a scanned interface needs at least 4 points (mm)")
    height = float(p[:, 1].max())
    if height <= 0:
        raise ValueError("geometry.outline: the scanned interface lies below the floor")
    eps, depth = 1e-3 * height, 0.1 * height
    p = p.copy()
    p[0, 1] = min(p[0, 1], -eps)
    p[-1, 1] = min(p[-1, 1], -eps)
    # counterclockwise: below the upstream foot, along under the colony, up to the
    # downstream foot, over the top back to the upstream foot (the interface reversed)
    wp = WorkPlane().MoveTo(p[0, 0], -depth).LineTo(p[-1, 0], -depth).LineTo(*p[-1])
    wp = wp.Spline([gp_Pnt2d(float(x), float(y)) for x, y in p[-2::-1]])
    full = wp.Close().Face()
    return full, float(p[:, 0].min()), float(p[:, 0].max()), height


def build_mesh(geometry: dict[str, Any], mesh_cfg: dict[str, Any]) -> BiofilmMesh:
    """Mesh the flow cell.

    Parameters
    ----------
    geometry
        Validated ``geometry`` section of the fsi config (mm).
    mesh_cfg
        ``mesh`` section with the preset resolved: ``h_interface`` (interface and biofilm
        base), ``h_solid`` (biofilm interior), ``h_bulk`` (elsewhere), all mm;
        ``grading`` (netgen mesh grading, larger = faster coarsening) and ``curve_order``.

    Returns
    -------
    BiofilmMesh
    """
    import ngsolve as ng
    from netgen.occ import Glue, OCCGeometry, WorkPlane, X, Y

    L = float(geometry["length"])
    H = float(geometry["channel_height"])
    patch, lo, hi, height = _outline_face(geometry)
    patch.edges.name = "interface"
    patch.edges.Min(Y).name = "biofilm_floor"

    solids = []
    sub = geometry["subdomains"]
    if sub["enabled"]:
        c0, c1 = (float(c) for c in sub["cuts"])
        if not 0.0 < c0 < c1 < 1.0:
            raise ValueError("geometry.subdomains.cuts must satisfy 0 < cuts[0] < cuts[1] < 1")
        w = hi - lo + 2.0
        band0 = WorkPlane().MoveTo(lo - 1.0, -1.0).Rectangle(w, 1.0 + c0 * height).Face()
        band1 = WorkPlane().MoveTo(lo - 1.0, c0 * height).Rectangle(w, (c1 - c0) * height).Face()
        band2 = WorkPlane().MoveTo(lo - 1.0, c1 * height).Rectangle(w, 2.0 * H).Face()
        for band in (band0, band1, band2):
            band.edges.name = "cut"
        pieces = [patch * band0, patch * band1, patch * band2]
        for name, piece in zip(SOLID_SUBDOMAINS, pieces):
            piece.faces.name = name
            solids.append(piece)
        regions = list(SOLID_SUBDOMAINS)
    else:
        patch.faces.name = "biofilm"
        solids.append(patch)
        regions = ["biofilm"]

    channel = WorkPlane().Rectangle(L, H).Face()
    channel.edges.Min(X).name = "inlet"
    channel.edges.Max(X).name = "outlet"
    channel.edges.Min(Y).name = "floor"
    channel.edges.Max(Y).name = "top"
    fluid = channel - patch
    fluid.faces.name = "fluid"
    shape = Glue([fluid, *solids])
    h_if = float(mesh_cfg["h_interface"])
    for e in shape.edges:
        if e.name in ("interface", "cut", "biofilm_floor"):
            e.maxh = h_if
    for f in shape.faces:
        if f.name != "fluid":
            f.maxh = float(mesh_cfg["h_solid"])
    mesh = ng.Mesh(generate_mesh(OCCGeometry(shape, dim=2), maxh=float(mesh_cfg["h_bulk"]),
                                 grading=float(mesh_cfg["grading"])))
    mesh.Curve(int(mesh_cfg["curve_order"]))
    verts, coords, segs = interface_chain(mesh, "interface")
    return BiofilmMesh(mesh, regions, verts, coords, segs, height)


def interface_chain(mesh: Any, boundary: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ordered vertices of an open boundary chain.

    Parameters
    ----------
    mesh
        NGSolve mesh.
    boundary
        Boundary name of the chain (e.g. ``"interface"``).

    Returns
    -------
    vertices : (n,) int
        Vertex numbers, from the end with the smaller x (upstream) to the other end.
    coords : (n, 2) float
        Vertex coordinates.
    segments : (n - 1, 2) int
        ``[[0, 1], [1, 2], ...]``.
    """
    import ngsolve as ng

    edges = []
    for el in mesh.Elements(ng.BND):
        if el.mat == boundary:
            vs = [v.nr for v in el.vertices]
            edges.append((vs[0], vs[1]))
    if not edges:
        raise ValueError(f"mesh has no boundary named '{boundary}'")
    adj: dict[int, list[int]] = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    ends = [v for v, nb in adj.items() if len(nb) == 1]
    if len(ends) != 2 or any(len(nb) > 2 for nb in adj.values()):
        raise ValueError(f"boundary '{boundary}' is not a single open chain")
    xy = {v: np.array(mesh.vertices[v].point) for v in adj}
    start = min(ends, key=lambda v: (xy[v][0], xy[v][1]))
    order = [start]
    prev = -1
    cur = start
    while len(order) < len(adj):
        nxt = next(n for n in adj[cur] if n != prev)
        prev, cur = cur, nxt
        order.append(cur)
    verts = np.array(order, dtype=int)
    coords = np.array([xy[v] for v in order], dtype=float)
    segs = np.column_stack([np.arange(len(order) - 1), np.arange(1, len(order))]).astype(int)
    return verts, coords, segs

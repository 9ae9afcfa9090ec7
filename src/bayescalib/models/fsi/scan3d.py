"""The 3D model's colony from a scan: a height field over the floor, as an OpenCascade cutter.

``geometry.dim: 3`` with ``geometry.shape: scan`` meshes the channel with the colony of a
recording at zero (or the lowest) flow, the field's practice (Picioreanu et al. 2018):
the scanned colony is the model's undeformed biofilm. The scan arrives as a
triangulated surface in mm (:class:`bayescalib.geometry.interface.Interface`: points
``(n, 3)``, triangles ``(m, 3)``, rim on the floor ``y = 0``, normals into the fluid),
from a surface file (:func:`bayescalib.io.surfaces.read_surface`) or from an OCT
volume (:func:`bayescalib.io.volumes.read_volume_surface`; its substrate must lie on
y = 0, :func:`bayescalib.io.volumes.substrate_offset`). This module turns it
into the solid the mesher cuts out of the channel box, in four steps:

1. *Height field.* A colony imaged from above is a height field ``y = h(x, z)`` over
   its footprint on the floor. The surface's triangles are split by the sign of their
   normal's ``y`` component (normals into the fluid: up-facing triangles are the top
   of the colony, down-facing ones an overhang); when the down-facing triangles'
   projected area exceeds :data:`OVERHANG_SHARE` of the up-facing ones' the scan is
   refused (an overhang is not a height field). ``h`` is sampled on a regular grid of
   spacing ``d`` (``geometry.scan.spacing``; default :data:`GRID_CELLS` cells across
   the footprint's larger extent) by linear interpolation on the up-facing triangles
   (their highest crossing of the vertical line through the node).
2. *Continuation below the floor.* Outside the footprint the field is continued
   below ``y = 0`` as a mirror image of the colony at the rim: a node at distance
   ``s`` outside the rim (the boundary edges of the surface, on the floor) takes the
   negative of the height at the mirror point ``2 q - p`` (``q`` the nearest rim
   point), at least ``s`` times half the colony's mean slope (so far from the rim it
   keeps falling). Odd about the rim, the field keeps its zero line on the rim when
   it is smoothed (the footprint stays where the scan has it), and a steep rim (a
   half-ellipsoid's is vertical) becomes an inflection of the smoothed field, not a
   kink that the mesher would refine. The grid extends a margin of
   ``max(4 d, 3 sigma)`` beyond the footprint, where the field is below the floor.
3. *Smoothing.* A Gaussian filter of standard deviation ``sigma``
   (``geometry.scan.smoothing``; default :data:`SMOOTHING_SPACINGS` = 2 grid
   spacings, as the 2D scans' two pixel sizes) removes the voxel or triangle
   staircase (and the vertical rim's infinite slope) that would otherwise become
   mesh detail. Its price: a steep rim is rounded, and the colony loses volume there
   (the half-ellipsoid: 4.4 % at the default, 1.6 % at one spacing; a colony whose
   rims are steep over a larger share of its volume loses more, 19 % for the two
   0.2-0.3 mm bumps of ``tests/test_scan3d.py`` smoothed at 50 um). Steps 1-3 run
   once, when the study is read (:meth:`bayescalib.study.Study._resolve_geometry`),
   and the grid's heights fill ``geometry.height_field`` (rounded to 1e-9 mm), so
   every solve depends on the geometry's numbers and a changed scan reruns the
   solves; no solve reads the file.
4. *Cutter.* ``netgen.occ.SplineSurfaceInterpolation`` puts a bicubic B-spline
   surface through the grid's points ``(x, h, z)``; the face extruded downward below
   the floor is the cutter, and as for the analytic half-ellipsoid
   (:func:`bayescalib.models.fsi.geometry3d.build_mesh_3d`) ``colony = cutter * box``,
   ``fluid = box - cutter``: the colony is the part of the cutter above the floor,
   the boundary names (``interface``, ``biofilm_floor``, ``floor``, ...) and the
   rest of the solver are unchanged.

Measured (``benchmarks/bench_scan3d.py --repeats 3``, 2026-11-27; NGSolve 6.2.2608, one
thread on the shared 2-core development machine under a load of about 8, so the
times are noisy to a factor 2: the analytic very_coarse solve took 5.2 s and 11.1 s in
two runs). The default half-ellipsoid (width 0.6, height 0.4, depth 0.6 mm) in the
default 2 x 1 x 1 mm channel, E = 400 Pa, nu = 0.3, default inflow, cold solves from
rest; "scan" is its surface triangulated (24 rings x 96 points), written as STL and
read back, on the default 10 um grid; "voxels" the marching-cubes surface of a 10 um
voxel mask of it (:func:`bayescalib.geometry.volume.volume_surface`). Medians of 3;
differences against the analytic colony on the same preset:

============  =============  =====  ======  =======  ======  ==========  ======
preset        colony         tets   mesh s  solve s  volume  area        max |d|
============  =============  =====  ======  =======  ======  ==========  ======
very_coarse   analytic       662    8.6     11.1     --      --          --
very_coarse   scan, 20 um    556    11.2    7.5      -4.4 %  -2.7 %      +7.2 %
very_coarse   scan, 10 um    1148   6.3     11.5     -1.5 %  -0.9 %      -3.0 %
very_coarse   voxels, 20 um  1020   2.3     7.4      -3.3 %  -2.0 %      -4.8 %
coarse        analytic       2040   3.9     31.2     --      --          --
coarse        scan, 20 um    1683   6.8     20.9     -4.2 %  -2.5 %      -5.0 %
coarse        scan, 10 um    1764   5.5     20.6     -1.6 %  -0.9 %      -3.3 %
coarse        voxels, 20 um  1884   4.5     17.8     -3.4 %  -2.0 %      -6.8 %
============  =============  =====  ======  =======  ======  ==========  ======

(20 um: the default smoothing, two grid spacings; 10 um: one.) Making the height field
takes 0.2-0.7 s. The maximum displacement is the least stable figure: the same scan
at one spacing of 0.6 mm / 60 (1e-6 mm from the 10 um above) meshed into 1090
tetrahedra on very_coarse and gave +0.5 % (coarse: -0.4 %), so a few per cent of it is
the mesh's luck; the rest, a few per cent low, follows the volume the smoothing takes
off the steep rim. At one grid spacing a voxel surface is not smooth enough: its
residual staircase made 4300 tetrahedra on very_coarse and a solve that failed after
5 min, hence the default of two.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface

__all__ = ["FLOOR_TOL_MM", "GRID_CELLS", "OVERHANG_SHARE", "SMOOTHING_SPACINGS", "HeightField",
           "ScanError", "height_field", "height_field_cutter", "scan_height_field", "star_surface", "validate_height_field"]

#: default grid: this many cells across the footprint's larger extent
GRID_CELLS = 60
#: default smoothing: this many grid spacings (as 2D images' two pixel sizes)
SMOOTHING_SPACINGS = 2.0
#: down-facing triangles' projected area above this share of the up-facing ones': overhang
OVERHANG_SHARE = 0.02
#: the rim farther than this from y = 0 (mm) is a misplaced scan (as in 2D, io.colony)
FLOOR_TOL_MM = 0.01
#: decimals of the heights in the config (1e-9 mm)
DECIMALS = 9


class ScanError(ValueError):
    """A scanned colony the 3D model cannot take (the message names the key and value)."""


@dataclass
class HeightField:
    """The colony as heights over a regular grid of the floor, continued below it.

    Attributes
    ----------
    origin : ndarray, shape (2,)
        ``(x, z)`` of the node ``heights[0, 0]``, mm.
    spacing : float
        Grid spacing in x and z, mm.
    heights : ndarray, shape (nx, nz)
        ``h(x_i, z_j)``, mm: positive over the footprint, negative outside it (the
        continuation below the floor, module docstring step 2).
    info : dict
        What was done (plain values): ``spacing_mm``, ``smoothing_mm``, ``margin_mm``,
        ``footprint_area_mm2``, ``volume_mm3`` (of the raw surface over the floor),
        ``height_mm``, ``x_range_mm``, ``z_range_mm``, ``overhang_share``.
    """

    origin: np.ndarray
    spacing: float
    heights: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def x(self) -> np.ndarray:
        """Grid x, shape (nx,), mm."""
        return self.origin[0] + self.spacing * np.arange(self.heights.shape[0])

    @property
    def z(self) -> np.ndarray:
        """Grid z, shape (nz,), mm."""
        return self.origin[1] + self.spacing * np.arange(self.heights.shape[1])

    def to_config(self) -> dict[str, Any]:
        """The ``geometry.height_field`` value: ``origin`` [x, z], ``spacing`` and
        ``heights`` (nx rows of nz), mm, rounded to 1e-9 mm."""
        return {"origin": [round(float(v), DECIMALS) for v in self.origin],
                "spacing": round(float(self.spacing), DECIMALS),
                "heights": np.round(self.heights, DECIMALS).tolist()}

    @classmethod
    def from_config(cls, value: dict[str, Any]) -> HeightField:
        """The field of a ``geometry.height_field`` value (:meth:`to_config`)."""
        h = np.asarray(value["heights"], dtype=float)
        if h.ndim != 2 or min(h.shape) < 4:
            raise ScanError(f"geometry.height_field.heights: a grid of at least 4 x 4 "
                            f"heights is needed, got shape {h.shape}")
        return cls(np.asarray(value["origin"], dtype=float), float(value["spacing"]), h)


def _segment_distance(p: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points ``p`` (N, 2) to the nearest of segments ``seg`` (k, 2, 2),
    and that nearest point (N, 2)."""
    best = np.full(len(p), np.inf)
    near = np.zeros_like(p)
    a, b = seg[:, 0], seg[:, 1]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    ll[ll == 0] = 1.0
    for start in range(0, len(p), 512):  # chunks: (512, k) arrays
        q = p[start:start + 512, None, :]
        t = np.clip(np.einsum("nkj,kj->nk", q - a, ab) / ll, 0.0, 1.0)
        c = a + t[..., None] * ab
        d2 = np.sum((q - c) ** 2, axis=-1)
        k = np.argmin(d2, axis=1)
        rows = np.arange(len(k))
        best[start:start + 512] = np.sqrt(d2[rows, k])
        near[start:start + 512] = c[rows, k]
    return best, near


def height_field(surface: Interface, *, spacing: float | None = None,
                 smoothing: float | None = None, name: str = "geometry.scan",
                 floor_tol: float = FLOOR_TOL_MM) -> HeightField:
    """The colony of a triangulated surface as a smoothed height field (module docstring).

    Parameters
    ----------
    surface : Interface
        Points ``(n, 3)`` and triangles ``(m, 3)`` in mm, the rim (boundary edges) on
        the floor ``y = 0``, normals into the fluid (as
        :func:`bayescalib.io.surfaces.read_surface` and
        :func:`bayescalib.geometry.volume.volume_surface` return it).
    spacing : float, optional
        Grid spacing, mm (None: the footprint's larger extent / :data:`GRID_CELLS`).
    smoothing : float, optional
        Standard deviation of the Gaussian smoothing, mm (None:
        :data:`SMOOTHING_SPACINGS` grid spacings; 0: none).
    name : str
        The config key, for messages.
    floor_tol : float
        Largest distance of the rim from the floor, mm (an OCT volume's surface is cut on
        top of the bright substrate's blur, a voxel or two above it: its rim may lie that
        high, and the continuation below the floor carries the foot down to it).

    Returns
    -------
    HeightField

    Raises
    ------
    ScanError
        A 2D interface, a closed surface (no rim), a rim away from the floor, an
        overhang; each message names ``name``.
    """
    from scipy import ndimage

    from bayescalib.geometry.surface import boundary_edges

    if surface.dim != 3:
        raise ScanError(f"{name}: a 3D model's scan is a triangulated surface, got a 2D curve")
    pts, tri = surface.points, surface.cells
    rim = boundary_edges(tri)
    seg = pts[rim][:, :, [0, 2]]  # the rim as (x, z) segments, (k, 2, 2)
    if len(seg) == 0:
        raise ScanError(f"{name}: the surface is closed; the colony's surface is open at its "
                        "rim on the floor")
    rim_y = pts[np.unique(rim), 1]
    if np.abs(rim_y).max() > floor_tol:
        raise ScanError(
            f"{name}: the colony's rim (its base on the substrate) lies at y = "
            f"{rim_y.min():.4g} to {rim_y.max():.4g} mm, but the flow cell's floor is y = 0 "
            f"(tolerance {floor_tol:g} mm): shift the surface (or give geometry.scan.floor; "
            "a volume: its origin) so that the colony sits on y = 0")
    p = pts[tri]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # 2 x area x unit normal
    up = nrm[:, 1] > 0
    a_up = 0.5 * float(nrm[up, 1].sum())
    a_down = -0.5 * float(nrm[~up, 1].sum())
    share = a_down / a_up if a_up > 0 else np.inf
    if share > OVERHANG_SHARE:
        worst = int(np.argmin(nrm[:, 1]))
        c = p[worst].mean(axis=0)
        raise ScanError(
            f"{name}: the colony overhangs (down-facing surface with {100 * share:.3g} % of "
            f"the footprint's area projected on the floor, more than {100 * OVERHANG_SHARE:g} %; "
            f"e.g. at x = {c[0]:.4g}, y = {c[1]:.4g}, z = {c[2]:.4g} mm): the 3D model takes a "
            "colony imaged from above as a height field y = h(x, z), without overhangs")
    lo = seg.reshape(-1, 2).min(axis=0)
    hi = seg.reshape(-1, 2).max(axis=0)
    extent = float((hi - lo).max())
    d = extent / GRID_CELLS if spacing is None else float(spacing)
    if not d > 0 or extent / d > 2000:
        raise ScanError(f"{name}.spacing: {d:g} mm gives more than 2000 grid cells across "
                        f"the colony ({extent:.4g} mm): use a larger spacing")
    sigma = SMOOTHING_SPACINGS * d if smoothing is None else float(smoothing)
    margin = max(4.0 * d, 3.0 * sigma)
    n = np.ceil((hi - lo + 2.0 * margin) / d).astype(int) + 1
    origin = lo - margin - 0.5 * ((n - 1) * d - (hi - lo + 2.0 * margin))  # centred
    gx = origin[0] + d * np.arange(n[0])
    gz = origin[1] + d * np.arange(n[1])
    h_in = np.full((n[0], n[1]), -np.inf)
    eps = 1e-9
    for t in np.flatnonzero(up):
        v = p[t]
        xz = v[:, [0, 2]]
        i0, i1 = np.searchsorted(gx, [xz[:, 0].min() - eps, xz[:, 0].max() + eps])
        j0, j1 = np.searchsorted(gz, [xz[:, 1].min() - eps, xz[:, 1].max() + eps])
        if i1 <= i0 or j1 <= j0:
            continue
        X, Z = np.meshgrid(gx[i0:i1], gz[j0:j1], indexing="ij")
        e1, e2 = xz[1] - xz[0], xz[2] - xz[0]
        det = e1[0] * e2[1] - e1[1] * e2[0]
        if det == 0:
            continue
        rx, rz = X - xz[0, 0], Z - xz[0, 1]
        l1 = (rx * e2[1] - rz * e2[0]) / det
        l2 = (e1[0] * rz - e1[1] * rx) / det
        inside = (l1 >= -eps) & (l2 >= -eps) & (l1 + l2 <= 1 + eps)
        y = v[0, 1] + l1 * (v[1, 1] - v[0, 1]) + l2 * (v[2, 1] - v[0, 1])
        block = h_in[i0:i1, j0:j1]
        h_in[i0:i1, j0:j1] = np.where(inside, np.maximum(block, y), block)
    covered = np.isfinite(h_in)
    top = np.where(covered, np.maximum(h_in, 0.0), 0.0)
    height = float(pts[:, 1].max())
    slope = 0.5 * height / (0.5 * extent)  # half the colony's mean slope
    out = np.argwhere(~covered)
    nodes = np.column_stack([gx[out[:, 0]], gz[out[:, 1]]])
    dist, near = _segment_distance(nodes, seg)
    mirror = 2.0 * near - nodes
    mirrored = ndimage.map_coordinates(top, [(mirror[:, 0] - origin[0]) / d,
                                             (mirror[:, 1] - origin[1]) / d],
                                       order=1, mode="constant", cval=0.0)
    h = top.copy()
    h[out[:, 0], out[:, 1]] = -np.maximum(mirrored, slope * dist)
    if sigma > 0:
        h = ndimage.gaussian_filter(h, sigma / d, mode="nearest")
    edge = max(h[0].max(), h[-1].max(), h[:, 0].max(), h[:, -1].max())
    if edge >= 0:  # the margin is wider than the smoothing reaches: not expected
        raise ScanError(f"{name}: the smoothed height field reaches the floor at the grid's "
                        f"edge ({edge:.3g} mm): use a smaller geometry.scan.smoothing")
    foot = covered.sum() * d * d
    info = {"spacing_mm": d, "smoothing_mm": sigma, "margin_mm": margin,
            "footprint_area_mm2": float(foot), "volume_mm3": float(top.sum() * d * d),
            "height_mm": height, "x_range_mm": [float(lo[0]), float(hi[0])],
            "z_range_mm": [float(lo[1]), float(hi[1])], "overhang_share": float(share),
            "grid": [int(n[0]), int(n[1])]}
    return HeightField(origin, d, h, info)


def validate_height_field(field_: HeightField, *, length: float, channel_height: float,
                          channel_width: float, min_gap: float, units: str = "mm",
                          name: str = "geometry.scan") -> None:
    """Refuse a colony the channel cannot hold with a gap to its walls and top.

    Parameters
    ----------
    field_ : HeightField
    length, channel_height, channel_width : float
        The channel ``[0, L] x [0, H] x [0, W]``, mm.
    min_gap : float
        Narrowest gap between the colony and the inlet, outlet, side walls and top
        the mesh can resolve, mm (about two interface elements).
    units : str
        The unit the file was read in, for the hint.
    name : str
        The config key.

    Raises
    ------
    ScanError
        Naming ``name``, the colony's extent and the channel's.
    """
    x, z, h = field_.x, field_.z, field_.heights
    above = h > 0
    if not above.any():
        raise ScanError(f"{name}: nothing of the colony lies above the floor")
    ii, jj = np.nonzero(above)
    xl, xh = x[ii].min() - field_.spacing, x[ii].max() + field_.spacing
    zl, zh = z[jj].min() - field_.spacing, z[jj].max() + field_.spacing
    top = float(h.max())
    hint = f" (read as {units}: check geometry.scan.units)"
    big = (xh - xl) > length or (zh - zl) > channel_width or top > channel_height
    if big:
        raise ScanError(
            f"{name}: the colony ({xh - xl:.4g} x {top:.4g} x {zh - zl:.4g} mm in x, y, z) is "
            f"larger than the channel ({length:g} x {channel_height:g} x {channel_width:g} mm)"
            + hint)
    if xl < min_gap or xh > length - min_gap:
        raise ScanError(
            f"{name}: the colony spans x = {xl:.4g} to {xh:.4g} mm, not inside the channel "
            f"(0 to {length:g} mm) with a gap of {min_gap:.3g} mm to the inlet and outlet: "
            "check the scan's position and units")
    if zl < min_gap or zh > channel_width - min_gap:
        raise ScanError(
            f"{name}: the colony spans z = {zl:.4g} to {zh:.4g} mm, touching the side walls "
            f"(z = 0 and {channel_width:g} mm; a gap of {min_gap:.3g} mm is needed): check "
            "the scan's position and units, or widen geometry.channel_width")
    if top > channel_height - min_gap:
        raise ScanError(
            f"{name}: the colony is {top:.4g} mm high, within {min_gap:.3g} mm of the channel's "
            f"top ({channel_height:g} mm): check the scan's units" + hint)


def _validate_size(surface: Interface, geometry: dict[str, Any], min_gap: float, units: str,
                   name: str, volume: bool) -> None:
    """Refuse a scanned colony larger than the channel or smaller than the gap the mesh
    resolves (about an interface element), before its height field: the unit slip it is
    (a volume in um read as m, a voxel size and origin in mm under units um) would
    otherwise be named after its consequence (a rim far above the floor), naming the
    unit in which its size fits the channel."""
    from bayescalib.io.observations import unit_hint

    ext = np.ptp(surface.points, axis=0)
    chan = np.array([float(geometry["length"]), float(geometry["channel_height"]),
                     float(geometry["channel_width"])])
    ratio = float(np.max(ext / chan))
    if ratio <= 1.0 and float(np.max(ext)) >= min_gap:
        return
    u = unit_hint(ratio, units, 0.05, 1.0)
    size = " x ".join(f"{v:.4g}" for v in ext)
    raise ScanError(
        f"{name}: the colony ({size} mm in x, y, z) is "
        + (f"larger than the channel ({chan[0]:g} x {chan[1]:g} x {chan[2]:g} mm)"
           if ratio > 1.0 else f"smaller than the mesh resolves ({min_gap:.3g} mm)")
        + f" (read as {units}: check geometry.scan.units"
        + (", pixel_size and origin" if volume else "")
        + (f"; the sizes fit if they are in {u}, units: {u}" if u else "") + ")")


def scan_height_field(geometry: dict[str, Any], *, min_gap: float,
                      key: str = "geometry") -> HeightField:
    """The height field of ``geometry.scan``'s colony, checked against the channel.

    Parameters
    ----------
    geometry : dict
        Validated ``geometry`` section with ``dim: 3`` and ``shape: scan``: its
        ``scan`` (``path`` a surface file, ``units``, ``floor``, ``smoothing``, optional
        ``spacing``) and the channel's ``length``, ``channel_height``, ``channel_width``.
    min_gap : float
        Gap the colony must keep to the inlet, outlet, side walls and top, mm.
    key : str
        The geometry section's config key, for messages (``<key>.scan...``).

    Returns
    -------
    HeightField

    Raises
    ------
    ScanError
        A file that is not a surface, keys that apply to images, a floor or rim away
        from y = 0, an unreadable surface, an overhang, a colony outside the channel
        or too close to its walls; the message names the key and the value.
    """
    from pathlib import Path

    from bayescalib.geometry.surface import UNITS
    from bayescalib.io.observations import ObservationError, cut_height, read_interface_info
    from bayescalib.io.surfaces import SURFACE_SUFFIXES, read_surface
    from bayescalib.io.volumes import is_volume, substrate_offset

    scan = geometry["scan"]
    path = Path(scan["path"])
    volume = path.exists() and is_volume(path)
    if path.suffix.lower() not in SURFACE_SUFFIXES and not volume:
        raise ScanError(
            f"{key}.scan.path = '{path}': a 3D model's scan is a triangulated surface "
            f"({', '.join(sorted(SURFACE_SUFFIXES))}) or an OCT volume (a folder of "
            "B-scans, .npy, a multi-page TIFF) of the colony at zero flow")
    for name in ("colony",) if volume else ("pixel_size", "origin", "colony"):
        if scan.get(name) is not None:
            raise ScanError(f"{key}.scan.{name} applies to images (2D scans); leave it out "
                            f"for a {'volume' if volume else 'surface file'}"
                            + (" (component picks a colony)" if name == "colony" else ""))
    f = UNITS[scan["units"]]
    floor = scan["floor"]
    if floor is not None and not isinstance(floor, str) and abs(float(floor) * f) > FLOOR_TOL_MM:
        raise ScanError(
            f"{key}.scan.floor = {floor}: the substrate lies at y = {float(floor) * f:.4g} mm "
            "in the file's coordinates, but the flow cell's floor is y = 0: shift the surface "
            "so that the colony sits on y = 0")
    try:
        if volume:
            surface, info = read_interface_info(
                path, units=scan["units"], pixel_size=scan.get("pixel_size"),
                origin=scan.get("origin"), floor=floor, image=scan["image"],
                segmentation=scan["segmentation"], component=scan.get("component"))
            info["units"] = scan["units"]
        else:
            surface, info = read_surface(path, units=scan["units"], floor=floor,
                                         component=scan.get("component"))
    except ObservationError as exc:
        raise ScanError(f"{key}.scan: {exc}") from None
    spacing, smoothing = scan.get("spacing"), scan["smoothing"]
    name = f"{key}.scan ('{path}')"
    if volume:  # the substrate on y = 0 (the rim's check below allows the cut's height)
        why = substrate_offset(info, units=scan["units"], pixel_size=scan["pixel_size"],
                               origin=scan["origin"])
        if why:
            raise ScanError(f"{name}: {why}")
    _validate_size(surface, geometry, min_gap, info["units"], name, volume)
    cut = cut_height(surface, info) if volume else None
    try:
        field_ = height_field(surface, spacing=None if spacing is None else float(spacing) * f,
                              smoothing=None if smoothing is None else float(smoothing) * f,
                              name=name, floor_tol=FLOOR_TOL_MM + (cut or 0.0))
    except ScanError as exc:
        if not (volume and "overhangs" in str(exc) and (cut or 0.0) < FLOOR_TOL_MM):
            raise
        # a volume cut at its substrate (no band's halo to cut above): a steep foot's
        # voxel staircase faces down in places (2.3 % on the example recording without
        # its band, accepted with floor: 6 um)
        raise ScanError(f"{exc}; from a volume cut at the substrate, a steep foot's voxel "
                        "staircase faces down in places: give geometry.scan.floor a voxel "
                        f"above the substrate (it may lie up to {FLOOR_TOL_MM * 1e3:g} um "
                        "above y = 0)") from None
    validate_height_field(field_, length=float(geometry["length"]),
                          channel_height=float(geometry["channel_height"]),
                          channel_width=float(geometry["channel_width"]), min_gap=min_gap,
                          units=info["units"], name=name)
    field_.info["source"] = str(path)
    return field_


def height_field_cutter(field_: HeightField, channel_height: float) -> Any:
    """The OpenCascade solid whose part above the floor is the colony.

    Parameters
    ----------
    field_ : HeightField
    channel_height : float
        H, mm: the cutter reaches ``H / 2`` below the field's lowest point.

    Returns
    -------
    netgen.occ.TopoDS_Shape
        The B-spline face through the grid's points ``(x, h, z)``, extruded downward;
        its faces are all named ``interface`` (only the top face's part above the
        floor remains in ``cutter * box``).
    """
    from netgen.occ import SplineSurfaceInterpolation, Vec

    X, Z = np.meshgrid(field_.x, field_.z, indexing="ij")
    h = field_.heights
    face = SplineSurfaceInterpolation(np.ascontiguousarray(np.stack([X, h, Z], axis=-1)))
    depth = float(h.max() - h.min()) + 0.5 * float(channel_height)
    cutter = face.Extrude(Vec(0.0, -depth, 0.0))
    cutter.faces.name = "interface"
    return cutter


def star_surface(height: Any, centre: tuple[float, float], *, n_rings: int = 24,
                 n_angles: int = 64, max_radius: float = 10.0) -> Interface:
    """A synthetic colony's surface over a star-shaped footprint (tests, benchmarks).

    Parameters
    ----------
    height : callable
        ``height(x, z)`` -> heights (mm) for arrays of floor points, positive inside
        the footprint and ``<= 0`` outside it.
    centre : (float, float)
        ``(x, z)`` of a point from which every rim point is seen (the footprint is
        star-shaped about it), mm.
    n_rings, n_angles : int
        Rings from the top to the rim (clustered toward the rim, where a colony is
        steep) and points per ring.
    max_radius : float
        Bracket of the rim's distance from ``centre``, mm.

    Returns
    -------
    Interface
        Points ``(1 + n_rings * n_angles, 3)`` in mm, the rim ring at ``y = 0``,
        triangles oriented with normals up (out of the colony).
    """
    theta = 2.0 * np.pi * np.arange(n_angles) / n_angles
    d = np.column_stack([np.cos(theta), np.sin(theta)])
    lo, hi = np.zeros(n_angles), np.full(n_angles, float(max_radius))
    c = np.asarray(centre, dtype=float)
    for _ in range(60):  # bisection for the rim radius along each ray
        mid = 0.5 * (lo + hi)
        q = c + mid[:, None] * d
        inside = np.asarray(height(q[:, 0], q[:, 1])) > 0
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    rim = 0.5 * (lo + hi)
    s = np.sin(0.5 * np.pi * np.arange(1, n_rings + 1) / n_rings)  # clustered at the rim
    xz = c + (s[:, None, None] * rim[None, :, None]) * d[None, :, :]
    y = np.asarray(height(xz[..., 0], xz[..., 1]), dtype=float)
    y[-1] = 0.0
    top = np.array([[c[0], float(height(np.array([c[0]]), np.array([c[1]]))[0]), c[1]]])
    pts = np.vstack([top, np.column_stack([xz[..., 0].ravel(), np.maximum(y, 0).ravel(),
                                           xz[..., 1].ravel()])])

    def idx(r, j):
        return 1 + r * n_angles + (j % n_angles)

    tris = [[0, idx(0, j + 1), idx(0, j)] for j in range(n_angles)]
    for r in range(n_rings - 1):
        for j in range(n_angles):
            tris.append([idx(r, j), idx(r, j + 1), idx(r + 1, j + 1)])
            tris.append([idx(r, j), idx(r + 1, j + 1), idx(r + 1, j)])
    tri = np.array(tris, dtype=np.int64)
    p = pts[tri]
    if np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 1].sum() < 0:
        tri = tri[:, ::-1]
    return Interface.surface(pts, tri, name="star_surface")

"""The interface surface of a colony from an OCT volume (3D greyscale stack or mask).

The 3D analogue of :mod:`bayescalib.geometry.imaging`, with its conventions:

Volume and coordinates
----------------------
A volume is an array ``(nz, ny, nx)``: a stack of ``nz`` B-scans, each an image of
``ny`` rows (row 0 at the top, depth) and ``nx`` columns, or such a sequence of 2D
B-scans. With voxel sizes ``(dx, dy, dz)`` and ``origin = (x0, y0, z0)`` the position of
the centre of voxel ``[0, ny - 1, 0]`` (the bottom-left pixel of the first B-scan),
voxel ``[k, row, col]`` lies at

    ``x = x0 + col dx``, ``y = y0 + (ny - 1 - row) dy``, ``z = z0 + k dz``,

the 3D model's frame (:mod:`bayescalib.models.fsi.geometry3d`: x along the flow, y up,
z across; each B-scan is a plane ``z = const``, as in 2D). Sizes and origin are given
in ``units`` (``"mm"``, ``"um"`` or ``"m"``); there are no defaults.

Steps
-----
1. *Mask or scan* (``kind="auto"``: exactly two distinct values make a mask, the
   foreground the brighter one). A scan is segmented by the 2D segmentation's own
   function, in 3D (:func:`bayescalib.geometry.imaging.segment_scan`: Gaussian
   pre-filter of ``smooth`` voxels along every axis, a threshold in the scan's
   intensity or Otsu's, removal of foreground specks and background holes smaller
   than ``min_size`` voxels, 6-connected), with the schema's defaults
   (:func:`bayescalib.geometry.imaging.segmentation_options`).
2. *Floor* (``floor="auto"``): the 2D rules (:func:`bayescalib.geometry.imaging.find_floor`:
   a bright band, a thin full-extent band, the bottom of the foreground, or the
   volume's bottom face) applied to the layers ``row`` of the volume (every layer's
   voxels are the "columns" of the 2D rule). A number is a y in ``units``, rounded to the
   nearest layer edge; None is the volume's bottom face. Voxels below the floor are the
   substrate, whatever their segmentation.
3. *One colony, inside the volume.* The foreground above the floor is split into
   26-connected components; more than one is refused with their number and sizes
   (voxels, mm^3), unless ``component`` picks one (0 = the largest). A colony with
   voxels on a side face (x, z) or the top face of the volume is cut off by the field
   of view: refused, naming the faces. An empty mask (or a segmentation without
   foreground or background) is refused; so is a foreground filling the top layer
   (fluid bright and biofilm dark, an inverted volume; or B-scans upside down), and a
   floor found at the top with foreground only below it is named as B-scans upside down.
4. *Marching cubes* (:func:`skimage.measure.marching_cubes`, Lewiner, at level 0.5) of
   the colony (in its bounding box) on a substrate slab (two layers below the floor),
   padded with background: a closed surface whose slab face lies on the floor plane exactly, so
   that the cut at the floor (:func:`bayescalib.geometry.surface.colony_surface`)
   leaves the colony's surface with its rim on the floor. On a binary volume every
   vertex is the midpoint of a voxel edge between a foreground and a background
   centre, so it lies within half a voxel of the true boundary.
5. *Smoothing*: ``iterations`` Taubin steps (default
   :data:`bayescalib.geometry.surface.TAUBIN_ITERATIONS`), which take out the
   staircase; then the orientation (normals into the fluid).

6. *Positional uncertainty* (``sigma_mm`` of the reading record; :func:`positional_sigma`),
   the 3D version of the 2D segmentation's (:mod:`bayescalib.geometry.imaging`, item
   5), in quadrature: the mask's quantisation after marching cubes and smoothing,
   :data:`MASK_SURFACE_RMS` voxel edges along the surface's normal
   (``|(n_x dx, n_y dy, n_z dz)|``, area-weighted RMS over the surface: larger where
   the surface faces the coarse axis, e.g. the side flanks facing z for B-scans 8 um
   apart against 6 um pixels), and, for a scan, the image noise over the intensity
   gradient at the contour (the 2D estimate on the B-scan through the colony's middle,
   in its pixels, times the gain of the pre-filter's third axis: the 3D filter averages
   over one more axis than the 2D one). On the example recording
   (``examples/oct_colony3d``, ``benchmarks/volume_check.py``): 1.18 um (1.02 of
   quantisation, 0.59 of noise), where the segmented surface's RMS distance from the
   true one is 1.04-1.07 um above the cut (0.84 of it a systematic outward offset).
   It is a lower bound of the noise the model-form diagnosis assumes: with the
   Gaussian noise model and the data's own estimate alone (0.94 um) its check of the
   right model located "mismatches" of ~1 um on the side flanks, where the 8 um
   B-scan spacing lies along the normal.

Accuracy, measured on a half-ellipsoid mask (semi-axes 40 x 15 x 30 voxels,
tests/test_surface3d.py): vertices within 0.42 voxel of the true surface above the
lowest layer, 0.72 voxel in it (the foot's chamfer onto the floor); RMS distance 0.15
voxel (0.24 raw); volume -0.04 % (-0.15 % raw); area +1.0 % (+8.9 % raw, the
staircase). With anisotropic voxels the bound is half the largest voxel edge.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.surface import (
    TAUBIN_ITERATIONS,
    SurfaceError,
    colony_surface,
    pick_component,
    unit_factor,
)

__all__ = ["FOOT_SHARE", "MASK_SURFACE_RMS", "positional_sigma", "volume_surface"]

#: RMS distance of a binary mask's smoothed marching-cubes surface from the true one, in
#: voxel edges along the normal (tests/test_surface3d.py: 0.149 on a half-ellipsoid, 0.235
#: before the Taubin smoothing): the quantisation part of :func:`positional_sigma`
MASK_SURFACE_RMS = 0.15

#: with the floor at the bottom of the foreground (no substrate band), a lowest layer with
#: less than this share of the foreground of the layer above it is blur or speckle below
#: the colony's foot, not its foot: the floor is put above it
FOOT_SHARE = 0.1

_FACES = (("z min", 0, 0), ("z max", 0, -1), ("y max (top)", 1, 0), ("x min", 2, 0),
          ("x max", 2, -1))


def _triple(value: Any, what: str, where: str, unit: str) -> np.ndarray:
    if value is None:
        raise SurfaceError(f"{where}: no {what} given: pass {what}=(x, y, z) in {unit} "
                           "(there is no default)")
    v = np.asarray(value, dtype=float)
    if v.ndim == 0 and what == "voxel_size":
        v = np.full(3, float(v))
    if v.shape != (3,) or not np.isfinite(v).all():
        raise SurfaceError(f"{where}: {what} must be three finite numbers (x, y, z) in "
                           f"{unit}, got {value!r}")
    if what == "voxel_size" and np.any(v <= 0):
        raise SurfaceError(f"{where}: voxel_size must be > 0 {unit} along x, y and z, "
                           f"got {value!r}")
    return v


def volume_surface(
    volume: np.ndarray | Sequence[np.ndarray],
    *,
    voxel_size: float | Sequence[float] | None,
    units: str | None,
    origin: Sequence[float] | None,
    kind: str = "auto",
    segmentation: Mapping[str, Any] | None = None,
    floor: float | str | None = "auto",
    component: int | None = None,
    iterations: int = TAUBIN_ITERATIONS,
    name: str = "volume",
) -> tuple[Interface, dict[str, Any]]:
    """The fluid-biofilm surface of a colony in an OCT volume (module docstring).

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx), or sequence of nz arrays (ny, nx)
        Greyscale scan (biofilm bright) or mask (bool or two values); B-scan rows from
        the top.
    voxel_size : float or (float, float, float)
        ``(dx, dy, dz)`` in ``units`` (one number: cubic voxels).
    units : {"mm", "um", "m"}
        The unit of ``voxel_size``, ``origin`` and a numeric ``floor``.
    origin : (float, float, float)
        Position ``(x, y, z)`` of the centre of voxel ``[0, ny - 1, 0]``, in ``units``.
    kind : {"auto", "mask", "scan"}
    segmentation : mapping, optional
        ``smooth`` (voxels), ``threshold`` (intensity or ``"otsu"``), ``min_size``
        (voxels); missing ones take the schema's defaults.
    floor : "auto", float or None
        The substrate plane: found (step 2), a y in ``units``, or the volume's bottom face.
    component : int, optional
        Which colony to keep when there are several (0 = the largest).
    iterations : int
        Taubin smoothing iterations (0 = the raw marching-cubes surface).
    name : str
        The source, in error messages.

    Returns
    -------
    surface : Interface
        Vertices ``(n, 3)`` and triangles ``(m, 3)`` in mm, normals into the fluid, the
        base on the floor left out.
    info : dict
        ``shape`` [nz, ny, nx], ``kind``, ``threshold``, ``threshold_method``,
        ``voxel_size_mm``, ``origin_mm``, ``floor`` (``method``, ``row`` the layer edge,
        ``y_mm`` where the surface is cut; ``edge_y_mm`` a bright band's own top edge,
        the substrate's surface, below the cut by the band's blurred halo, else None),
        ``colonies`` (components above the floor), ``colony_voxels``, and
        the surface's (:func:`bayescalib.geometry.surface.colony_surface`):
        ``volume_mm3``, ``area_mm2``, ``volume_change``, ``smoothing_iterations``.

    Raises
    ------
    SurfaceError
        Naming the value: no unit, voxel size or origin; not 3D; NaN/inf; a single
        value; no foreground or no background; several colonies; a colony touching the
        volume's border.
    """
    from scipy.ndimage import label
    from skimage import measure

    from bayescalib.geometry import imaging

    f = unit_factor(units, name, "units")
    vox = _triple(voxel_size, "voxel_size", name, str(units)) * f
    org = _triple(origin, "origin", name, str(units)) * f
    if kind not in ("auto", "mask", "scan"):
        raise SurfaceError(f"{name}: kind must be 'auto', 'mask' or 'scan', got {kind!r}")
    try:
        vol = np.asarray(np.stack([np.asarray(b) for b in volume]) if not isinstance(
            volume, np.ndarray) else volume)
    except ValueError as exc:
        raise SurfaceError(f"{name}: the B-scans differ in shape ({exc})") from None
    if vol.ndim != 3 or min(vol.shape) < 2:
        raise SurfaceError(f"{name}: a volume is an array (nz, ny, nx) of at least 2 voxels "
                           f"along each axis (or a list of 2D B-scans), got shape {vol.shape}")
    img = vol.astype(float)
    if not np.isfinite(img).all():
        raise SurfaceError(f"{name}: the volume contains NaN/inf values")
    lo, hi = float(img.min()), float(img.max())
    if lo == hi:
        raise SurfaceError(f"{name}: the volume has a single value ({lo:g}): empty, "
                           "nothing to segment")
    if kind == "auto":
        kind = "mask" if np.unique(img).size == 2 else "scan"
    smoothed, blur = None, 0.0
    if kind == "mask":
        t = 0.5 * (lo + hi)
        mask, method = img > t, "midpoint"
    else:
        opts = imaging.segmentation_options(segmentation)
        try:
            mask, smoothed, t = imaging._segment(img, smooth=float(opts["smooth"]),
                                                 threshold=opts["threshold"],
                                                 min_size=int(opts["min_size"]))
        except ValueError as exc:
            raise SurfaceError(f"{name}: segmentation: {exc}") from None
        method, blur = ("otsu" if opts["threshold"] == "otsu" else "given"), float(opts["smooth"])
        where = f"(threshold {t:.6g} in the intensity range {lo:g} to {hi:g}, {method})"
        if not mask.any():
            raise SurfaceError(f"{name}: the segmentation finds no foreground (biofilm) {where}")
        if mask.all():
            raise SurfaceError(f"{name}: the segmentation finds no background (fluid) {where}")
    nz, ny, nx = mask.shape
    dx, dy, dz = vox
    top = float(mask[:, 0, :].mean())  # the top layer: fluid above a colony on the floor
    if top >= imaging.FLOOR_FULL_WIDTH:
        bright = "bright part" if kind == "scan" else "brighter value"
        raise SurfaceError(
            f"{name}: the foreground (the {bright}, taken for biofilm) fills {100 * top:.0f} % "
            "of the volume's top layer (row 0 of every B-scan): the fluid above the colony "
            "must be the dark part and the biofilm the bright one. This looks like an "
            "inverted volume (fluid bright, biofilm dark): invert its grey values"
            + (" (or check segmentation.threshold)" if kind == "scan" else "")
            + "; or its B-scans are upside down (row 0 must be the top, the substrate at "
            "the bottom): flip their rows")
    # ---- floor: a layer edge (row - 0.5 between rows row - 1 and row)
    if floor == "auto":
        flat = mask.transpose(1, 0, 2).reshape(ny, -1)
        sm = None if smoothed is None else smoothed.transpose(1, 0, 2).reshape(ny, -1)
        found = imaging.find_floor(flat, sm, blur, t if kind == "scan" else None)
        method_f = found["method"]
        row = ny - 0.5 if found["row"] is None else float(found["row"])
        edge_row = found.get("edge_row")
        if method_f == "foreground bottom":
            # no substrate band: the floor under the colony's foot, not under a sparse
            # layer of its blur or speckle below it (22 voxels under a foot of 5800 in the
            # example recording without its band), which would leave the foot's
            # underside in the surface as an overhang
            count = flat.sum(axis=1)
            low = round(row - 0.5)
            while low > 0 and count[low] < FOOT_SHARE * count[low - 1]:
                low -= 1
            row = low + 0.5
    elif floor is None:
        method_f, row, edge_row = "volume bottom", ny - 0.5, None
    elif isinstance(floor, str):
        raise SurfaceError(f"{name}: floor must be 'auto', a number (y in {units}) or None, "
                           f"got {floor!r}")
    else:
        y_f = float(floor) * f
        if not np.isfinite(y_f):
            raise SurfaceError(f"{name}: floor must be finite, got {floor!r}")
        edge = (ny - 1) - (y_f - org[1]) / dy
        row = float(np.clip(np.round(edge + 0.5), 0, ny)) - 0.5
        method_f, edge_row = "given", None
    n_above = round(row + 0.5)
    y_floor = float(org[1] + (ny - 1 - row) * dy)
    part = mask[:, :n_above, :]
    if not part.any():
        upside = (f"; the floor was found {'at the top' if row < 1 else 'in the upper half'} "
                  "of the B-scans, with foreground below it: are they upside down (row 0 "
                  "must be the top, the substrate at the bottom)? Flip their rows"
                  if row < 0.5 * ny and mask[:, n_above:, :].any() else "")
        raise SurfaceError(f"{name}: no foreground (biofilm) above the floor y = {y_floor:g} mm "
                           f"({method_f}): the mask is empty there" + upside)
    # ---- one colony
    lab, n_comp = label(part, structure=np.ones((3, 3, 3), dtype=bool))
    sizes = np.bincount(lab.ravel())[1:]
    cell = float(dx * dy * dz)
    chosen = pick_component(
        sizes, component, name,
        what="separate colonies (26-connected foreground components above the floor",
        describe=lambda j: f"{int(sizes[j])} voxels ({sizes[j] * cell:.4g} mm^3)",
        hint="crop the volume to one colony, or raise segmentation min_size to drop specks")
    colony = lab == chosen + 1
    touching = [f"{face} ({int(np.count_nonzero(np.take(colony, i, axis=ax)))} voxels)"
                for face, ax, i in _FACES if np.take(colony, i, axis=ax).any()]
    if touching:
        share = float(colony[:, n_above - 1, :].mean())  # the layer on the floor
        raise SurfaceError(
            f"{name}: the colony touches the volume's border on the {', '.join(touching)} "
            "face(s): it is cut off by the field of view; a colony must be surrounded by "
            "fluid on the sides and the top (image a larger region, or crop less; or the "
            "array's axes are in another order than (B-scan = z, row from the top = y, "
            "column = x): transpose it)"
            + (f"; but its lowest layer covers {share:.0%} of the B-scans' area: that is the "
               f"substrate, below which the floor was put ({method_f}, y = {y_floor:g} mm): "
               f"give floor, the y of the substrate's top in {units}, or check the origin's "
               "y" if share >= imaging.FLOOR_FULL_WIDTH else ""))
    # ---- marching cubes on the colony over a substrate slab, padded with background
    # (only the colony's bounding box: the rest of the slab is cut away anyway)
    k0, r0, c0 = (int(np.flatnonzero(colony.any(axis=ax))[0]) for ax in ((1, 2), (0, 2), (0, 1)))
    k1, c1 = (int(np.flatnonzero(colony.any(axis=ax))[-1]) + 1 for ax in ((1, 2), (0, 1)))
    box = colony[k0:k1, r0:, c0:c1]
    work = np.concatenate([box, np.ones((k1 - k0, 2, c1 - c0), dtype=bool)], axis=1)
    work = np.pad(work, 1).astype(np.float32)
    verts, faces, _, _ = measure.marching_cubes(work, 0.5, allow_degenerate=False)
    idx = verts - 1.0 + [k0, r0, c0]  # indices (k, row, col) of the volume
    pts = np.column_stack([org[0] + idx[:, 2] * dx, org[1] + (ny - 1 - idx[:, 1]) * dy,
                           org[2] + idx[:, 0] * dz])
    surf, sinfo = colony_surface(pts, faces.astype(np.int64), floor=y_floor,
                                 iterations=iterations, name=name)
    mid = None
    if smoothed is not None:  # the B-scan through the colony's middle, for the noise part
        k = (k0 + k1) // 2
        mid = (img[k], smoothed[k], mask[k], float(opts["smooth"]))
    sigma = positional_sigma(surf, vox, mid)
    info = {"shape": [nz, ny, nx], "kind": kind, "threshold": t, "threshold_method": method,
            "voxel_size_mm": vox.tolist(), "origin_mm": org.tolist(),
            "floor": {"method": method_f, "row": row, "y_mm": y_floor, "edge_y_mm": None
                      if edge_row is None else float(org[1] + (ny - 1 - edge_row) * dy)},
            "colonies": int(n_comp), "colony_voxels": int(sizes[chosen]), **sigma,
            **{key: sinfo[key] for key in ("volume_mm3", "area_mm2", "volume_change",
                                           "smoothing_iterations")}}
    return surf, info


def positional_sigma(surface: Interface, voxel_size: Sequence[float],
                     bscan: tuple[np.ndarray, np.ndarray, np.ndarray, float] | None = None
                     ) -> dict[str, float | None]:
    """Positional uncertainty of a surface segmented from a volume (module docstring,
    step 6), mm.

    Parameters
    ----------
    surface
        The segmented colony surface (mm).
    voxel_size
        ``(dx, dy, dz)``, mm.
    bscan
        For a scan: ``(image, smoothed, mask, smooth)`` of one B-scan through the
        colony (the 2D estimate's inputs, :mod:`bayescalib.geometry.imaging`); None for a
        mask (no image noise).

    Returns
    -------
    dict
        ``sigma_mm`` (the quadrature sum of the two parts), ``sigma_noise_mm`` (None
        for a mask or where the B-scan gives no estimate) and
        ``sigma_quantisation_mm``.
    """
    from scipy.ndimage import gaussian_filter1d

    from bayescalib.geometry.imaging import _positional_sigma

    vox = np.asarray(voxel_size, dtype=float)
    n = surface.normals
    w = surface.measures
    quant = MASK_SURFACE_RMS * float(np.sqrt(np.sum(w * np.sum((n * vox) ** 2, axis=1))
                                             / np.sum(w)))
    noise = None
    if bscan is not None:
        img, sm, m, smooth = bscan
        if m.any() and (~m).any():
            px = _positional_sigma(img, sm, m, smooth)["sigma_noise_px"]
            gain = 1.0  # the noise gain of the pre-filter along the B-scans' normal (z)
            if smooth > 0:
                r = int(np.ceil(4.0 * smooth)) + 1
                delta = np.zeros(2 * r + 1)
                delta[r] = 1.0
                gain = float(np.sqrt(np.sum(gaussian_filter1d(delta, smooth,
                                                              mode="constant") ** 2)))
            noise = None if px is None else float(px) * gain * float(np.mean(vox[:2]))
    total = quant if noise is None else float(np.hypot(noise, quant))
    return {"sigma_mm": total, "sigma_noise_mm": noise, "sigma_quantisation_mm": quant}

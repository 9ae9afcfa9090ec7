"""The model's undeformed colony read from a recording at zero (or the lowest) flow.

``forward_model.fsi.geometry.shape: scan`` takes the biofilm's undeformed shape
from ``geometry.scan``: a segmented mask or a raw greyscale B-scan (``.png``,
``.tif``), or an outline file (CSV, VTK) of the zero-flow interface. This module
reads the file and returns the fluid–biofilm interface above the substrate in mm,
smoothed at a stated length and resampled, by the steps of
:mod:`bayescalib.geometry.outline`:

* image: the mask (:func:`bayescalib.geometry.imaging.read_mask`: a mask as it is,
  a raw scan segmented), the substrate removed (pixels whose centre lies at or
  below the floor, so colonies are not joined through it), the colony chosen
  (``colony``: an x-range in the scan's units, else the largest; the choice is
  reported), its boundary traced with sub-pixel accuracy, cut at the floor,
  smoothed (``smoothing``, default two pixel sizes) and resampled;
* outline file: a closed outline (either orientation; the part above the floor is
  kept) or an open interface from foot to foot (either direction; its ends must lie
  on the floor), smoothed only when ``smoothing`` is given.

The floor is ``floor`` (in the scan's units), or for an image without one the
bottom edge of the image. The flow cell's floor is y = 0 in the model: a floor
farther than two pixels (or 10 um) from it means the origin does not put the
substrate where the model has it, and the scan is refused with the origin that
would.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry import outline as ol
from bayescalib.io.observations import (
    CSV_SUFFIXES,
    IMAGE_SUFFIXES,
    UNITS,
    VTK_SUFFIXES,
    ObservationError,
    read_interface,
)

__all__ = ["Colony", "read_colony"]

#: a floor this far from y = 0 (mm) is a misplaced scan, not a tolerance (also >= 2 pixels)
FLOOR_TOL_MM = 0.01


@dataclass
class Colony:
    """The undeformed colony taken from a recording.

    Attributes
    ----------
    interface : ndarray, shape (n, 2)
        Fluid–biofilm interface in mm, from the upstream foot to the downstream one,
        smoothed and resampled.
    info : dict
        What was done, in plain values: ``source`` (file), ``kind`` (mask, scan or
        outline), ``floor_mm``, ``pixel_size_mm`` (images), ``smoothing_mm``,
        ``spacing_mm``, ``area_mm2``, ``length_mm``, ``colony`` (the choice in
        words) and ``n_colonies``.
    """

    interface: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


def _fail(where: str, msg: str) -> ObservationError:
    return ObservationError(msg if msg.startswith(where) else f"{where}: {msg}")


def read_colony(scan: Mapping[str, Any], *, where: str = "geometry.scan") -> Colony:
    """Read the undeformed colony from the file a ``geometry.scan`` section names.

    Parameters
    ----------
    scan : mapping
        The validated ``geometry.scan`` section (its schema's defaults filled in):
        ``path``; ``units`` (m, mm, um: of coordinates, ``pixel_size``, ``origin``,
        ``floor``, ``colony`` and ``smoothing``); for images ``pixel_size`` and
        ``origin`` (required: the centre of the bottom-left pixel) and optionally
        ``image`` and ``segmentation`` (:func:`bayescalib.geometry.imaging.read_mask`);
        ``floor`` (number or None); ``colony`` ([lo, hi] x-range or None);
        ``smoothing`` (None: two pixels for images, none for outline files).
    where : str
        The config key, for messages.

    Returns
    -------
    Colony

    Raises
    ------
    ObservationError
        Naming ``where`` and the file: unreadable file, no colony, a colony cut by
        the image border, a floor away from y = 0, an open outline whose ends are
        not on the floor.
    """
    path = Path(scan["path"])
    units = scan["units"]
    f = UNITS[units]
    suffix = path.suffix.lower()
    if not path.is_file():
        raise _fail(where, f"'{path}' does not exist" + (
            f" (relative paths are read from {Path.cwd()})" if not path.is_absolute() else ""))
    if suffix not in CSV_SUFFIXES | VTK_SUFFIXES | IMAGE_SUFFIXES:
        known = sorted(CSV_SUFFIXES | VTK_SUFFIXES | IMAGE_SUFFIXES)
        raise _fail(where, f"'{path}' is not a supported file (suffixes: {', '.join(known)})")
    floor = scan["floor"]
    if isinstance(floor, str) and suffix not in IMAGE_SUFFIXES:
        raise _fail(where, f"floor: {floor!r} applies to images; give the substrate's y")
    if suffix in IMAGE_SUFFIXES:
        return _colony_from_image(path, scan, f, units, where)
    if scan["colony"] is not None:
        raise _fail(where, "colony (an x-range choosing one of several colonies) applies to "
                    "images; an outline file holds one colony")
    try:
        iface = read_interface(path, units=units)
    except ObservationError as exc:
        raise _fail(where, str(exc)) from None
    if iface.dim != 2 or not iface.is_chain():
        raise _fail(where, f"'{path}' must hold one ordered 2D curve (the zero-flow interface "
                    "or the colony's closed outline)")
    y_f = 0.0 if floor is None else float(floor) * f
    if abs(y_f) > FLOOR_TOL_MM:
        raise _fail(where, (
            f"'{path}': floor: the substrate lies at y = {y_f:.4g} mm in the file's "
            "coordinates, but the flow cell's floor is y = 0: shift the outline so that "
            "the colony sits on y = 0"))
    closed = iface.n_cells == iface.n_points
    try:
        pts = ol.interface_above_floor(iface.points, floor=y_f, closed=closed)
    except ol.OutlineError as exc:
        raise _fail(where, f"'{path}': {exc}") from None
    height = float(pts[:, 1].max() - y_f)
    if not closed:
        off = np.abs(pts[[0, -1], 1] - y_f)
        if off.max() > max(FLOOR_TOL_MM, 0.05 * height):
            raise _fail(where, (
                f"'{path}': the interface's ends lie at y = {pts[0, 1]:.4g} and "
                f"{pts[-1, 1]:.4g} mm, not on the floor (y = {y_f:g} mm): an open outline of "
                "the zero-flow interface runs from foot to foot on the substrate (or give the "
                "colony's closed outline)"))
    info = {"source": str(path), "kind": "outline", "n_colonies": 1,
            "colony": "one colony in the outline file"}
    smoothing = scan["smoothing"]
    return _finish(pts, y_f, None if smoothing is None else float(smoothing) * f, None,
                   info, where)


def _colony_from_image(path: Path, scan: Mapping[str, Any], f: float, units: str,
                       where: str) -> Colony:
    from bayescalib.geometry import imaging

    if scan.get("pixel_size") is None:
        raise _fail(where, f"pixel_size is required for the image '{path}' (the size of one "
                    f"pixel, in {units})")
    if scan.get("origin") is None:
        raise _fail(where, (
            f"origin is required for the image '{path}': the position (x, y) of the centre of "
            f"its bottom-left pixel in the flow cell, in {units}, so that the substrate lies "
            "at y = 0 and the colony where it is in the channel"))
    from bayescalib.io.volumes import is_volume

    if is_volume(path):  # the image reader would take its pages for colour channels
        raise _fail(where, (
            f"'{path}' is a multi-page TIFF (an OCT volume), but a 2D model's scan is one "
            "image: give the B-scan of the colony's section (a one-page TIFF or a PNG), or "
            "set forward_model.fsi.geometry.dim: 3 to model the colony in 3D"))
    s = float(scan["pixel_size"]) * f
    x0, y0 = (float(v) * f for v in scan["origin"])
    try:
        mask, seg = imaging.read_mask(path, image=scan["image"],
                                      segmentation=scan["segmentation"])
    except (ValueError, OSError) as exc:
        msg = str(exc)  # the image reader's messages start with the path
        raise _fail(where, msg if msg.startswith(str(path)) else f"'{path}': {msg}") from None
    why = imaging.inverted(seg)
    if why:
        raise _fail(where, why)
    h = mask.shape[0]
    floor = scan["floor"]
    y_cut = None  # where the trace is cut, when above the substrate's surface y_f
    if floor == "auto":
        found = seg.get("floor") or {}
        row = found.get("row")
        y_f = y0 - 0.5 * s if row is None else y0 + (h - 1 - float(row)) * s
        if found.get("edge_row") is not None:  # a bright band: cut above its halo,
            y_cut = y_f                          # the feet continued down to its surface
            y_f = y0 + (h - 1 - float(found["edge_row"])) * s
    elif floor is None:
        y_f = y0 - 0.5 * s  # the bottom edge of the image
    else:
        y_f = float(floor) * f
    y_cut = y_f if y_cut is None else y_cut
    if abs(y_f) > max(FLOOR_TOL_MM, 2.0 * s):
        raise _fail(where, (
            f"'{path}': the substrate lies at y = {y_f:.4g} mm in the scan's coordinates "
            f"(origin {list(scan['origin'])} {units}), but the flow cell's floor is y = 0: "
            f"with origin [{x0 / f:.6g}, {(y0 - y_f) / f:.6g}] {units} it would lie there"
            + _unit_slip(scan, units, y0, y_f, s)
            + ("; or, if the substrate is not the image's bottom edge (floor: null), give "
               "floor: auto to find it in the scan" if floor is None else "")))
    rows_y = y0 + (h - 1 - np.arange(h)) * s
    work = mask.copy()
    work[rows_y <= y_cut, :] = False
    cols = None
    if scan["colony"] is not None:
        lo, hi = (float(v) * f for v in scan["colony"])
        cols = ((lo - x0) / s, (hi - x0) / s)
    try:
        comp, choice = ol.select_colony(work, columns=cols, name=f"'{path}'")
        traced = imaging.mask_contour(comp, s, (x0, y0), drop_border=False, floor=y_cut,
                                      name=str(path))
        pts = ol.interface_above_floor(traced.points, floor=y_cut, closed=False)
    except (ol.OutlineError, ValueError) as exc:
        raise _fail(where, str(exc)) from None
    smoothing = scan["smoothing"]
    info = {"source": str(path), "kind": seg.get("kind", "mask"), "n_colonies": choice.n_colonies,
            "colony": choice.words, "pixel_size_mm": s,
            "colony_columns": list(choice.x_ranges[choice.index])}
    return _finish(pts, y_f, 2.0 * s if smoothing is None else float(smoothing) * f, s,
                   info, where)


def _unit_slip(scan: Mapping[str, Any], units: str, y0: float, y_f: float, s: float) -> str:
    """A hint when ``origin`` or ``pixel_size`` alone, read in another unit, puts the
    substrate found at ``y_f`` (mm, with origin y ``y0`` and pixel ``s``, mm) on y = 0:
    the usual cause of a floor far from it (e.g. an origin in um under ``units: mm``)."""
    f = UNITS[units]
    tol = FLOOR_TOL_MM
    others = [(u, g) for u, g in UNITS.items() if u != units]
    for u, g in others:  # the origin first: its numbers are copied from another tool
        if abs(y_f - y0 + y0 * g / f) <= max(tol, 2.0 * s):
            origin = ", ".join(f"{v * g / f:.6g}" for v in scan["origin"])
            return (f"; or the origin is in {u}, not {units}: origin [{origin}] {units} "
                    "puts the substrate on y = 0")
    for u, g in others:
        s_u = s * g / f
        if abs(y0 + (y_f - y0) * g / f) <= max(tol, 2.0 * min(s, s_u)):
            return (f"; or pixel_size is in {u}, not {units}: pixel_size "
                    f"{float(scan['pixel_size']) * g / f:.6g} {units} puts the substrate on "
                    "y = 0")
    return ""


def _finish(pts: np.ndarray, y_f: float, smoothing: float | None, pixel: float | None,
            info: dict[str, Any], where: str) -> Colony:
    """Smooth, resample and describe the interface."""
    sm = float(smoothing or 0.0)
    pts = ol.extend_to_floor(pts, y_f, reach=max(2.0 * (pixel or 0.0), sm, 1e-9))
    length = ol.curve_length(pts)
    if sm > 0:
        pts = ol.smooth_curve(pts, sm)
    # the mesh takes a spline through these points: spacing of the smoothing length
    # (a pixel at least), at most 400 points along the interface
    spacing = max(sm, pixel or 0.0, length / 400.0)
    if spacing > 0 and pts.shape[0] > 3:
        pts = ol.resample_curve(pts, spacing)
    info.update(floor_mm=float(y_f), smoothing_mm=sm, spacing_mm=float(spacing),
                area_mm2=ol.polygon_area(pts), length_mm=ol.curve_length(pts),
                x_range_mm=[float(pts[:, 0].min()), float(pts[:, 0].max())],
                height_mm=float(pts[:, 1].max() - y_f))
    return Colony(pts, info)

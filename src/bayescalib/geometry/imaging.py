"""Interface extraction from a segmented image (binary mask).

The observed interface is the 0.5 iso-line of the mask (foreground = biofilm,
value 1; background = fluid, value 0), traced with sub-pixel accuracy by
marching squares (:func:`skimage.measure.find_contours`); its points lie on
pixel edges, linearly interpolated, so a disc of radius R pixels is recovered
to well below one pixel.

Coordinates
-----------
Image row 0 is the top. With pixel size ``s`` (mm) and ``origin = (x0, y0)``
the physical position of the *centre of the bottom-left pixel*, pixel
``(row, col)`` of an image with ``H`` rows maps to
``x = x0 + col * s``, ``y = y0 + (H - 1 - row) * s`` (y up).

Which part is kept
------------------
* ``drop_border=True`` (default): the mask is not padded, so where the
  foreground touches the image border (the biofilm sitting on the floor at
  the bottom edge) no contour runs along the border: the curve is open and
  consists of the fluid-biofilm boundary only.
* ``drop_border=False``: the mask is padded with background, so the contour
  closes along the border/floor.
* ``floor=y_f`` (mm): for a floor inside the image (e.g. substrate pixels
  below the biofilm segmented as background), contour points with
  ``y <= y_f + s/2`` are removed and the longest remaining piece is kept, an
  open curve without the biofilm base.
If several contours exist (specks, holes), the longest is used.

Orientation follows :mod:`bayescalib.geometry.interface`: the curve is ordered so that
the foreground lies on its right, i.e. normals point into the background
(the fluid); it is checked by sampling the mask on both sides.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayescalib.geometry.interface import Interface

__all__ = ["load_mask", "mask_contour"]


class _MaskError(ValueError):
    pass


def load_mask(path: str | Path) -> np.ndarray:
    """Read a PNG/TIFF mask as a boolean array (foreground = value > half the maximum).

    Colour images use their first channel; an alpha channel is ignored.
    """
    from skimage import io

    img = np.asarray(io.imread(str(path)))
    if img.ndim == 3:
        img = img[..., 0]
    if img.ndim != 2:
        raise _MaskError(f"expected a 2D image, got shape {img.shape}")
    img = img.astype(float)
    top = float(img.max()) if img.size else 0.0
    if not np.isfinite(img).all():
        raise _MaskError("image contains NaN/inf values")
    return img > 0.5 * top if top > 0 else np.zeros(img.shape, dtype=bool)


def mask_contour(
    mask: np.ndarray,
    pixel_size: float,
    origin: tuple[float, float] = (0.0, 0.0),
    *,
    drop_border: bool = True,
    floor: float | None = None,
    name: str = "mask",
) -> Interface:
    """Sub-pixel fluid-biofilm contour of a binary mask.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
        Foreground (biofilm) True.
    pixel_size : float
        Pixel size in mm (> 0).
    origin : (float, float)
        Physical position (mm) of the centre of the bottom-left pixel.
    drop_border : bool
        Keep only the part of the boundary inside the image (see module docstring).
    floor : float, optional
        y of the floor in mm; the contour part on it is dropped.
    name : str
        Used in error messages.

    Returns
    -------
    Interface
        2D polyline (closed when the contour is closed), oriented with the
        foreground on its right.

    Raises
    ------
    ValueError
        If the mask has no foreground, no background, or no contour.
    """
    from skimage import measure

    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise _MaskError(f"{name}: mask must be 2D, got shape {m.shape}")
    if not m.any():
        raise _MaskError(f"{name}: the mask has no foreground pixels (nothing segmented)")
    if m.all():
        raise _MaskError(f"{name}: the mask is foreground everywhere (no interface)")
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise _MaskError(f"{name}: pixel size must be > 0 mm, got {pixel_size}")
    pad = 0 if drop_border else 1
    work = np.pad(m, pad).astype(float) if pad else m.astype(float)
    contours = measure.find_contours(work, 0.5)
    if not contours:
        raise _MaskError(f"{name}: no interface found in the mask")
    rc = max(contours, key=lambda c: float(np.sum(np.linalg.norm(np.diff(c, axis=0), axis=1))))
    rc = rc - pad
    closed = rc.shape[0] > 3 and np.allclose(rc[0], rc[-1])
    if closed:
        rc = rc[:-1]
    keep = np.r_[True, np.any(np.abs(np.diff(rc, axis=0)) > 1e-9, axis=1)]
    rc = rc[keep]
    if rc.shape[0] < 2:
        raise _MaskError(f"{name}: the interface in the mask is a single point")
    h = m.shape[0]
    s = float(pixel_size)
    x0, y0 = float(origin[0]), float(origin[1])
    pts = np.column_stack([x0 + rc[:, 1] * s, y0 + (h - 1 - rc[:, 0]) * s])
    if floor is not None:
        pts, closed = _drop_floor(pts, closed, float(floor) + 0.5 * s, name)
    curve = Interface.polyline(pts, closed=closed and pts.shape[0] >= 3, name=name)
    # orientation: foreground must be on the right (opposite to the normal)
    probe_in = curve.centres - 0.5 * s * curve.normals
    probe_out = curve.centres + 0.5 * s * curve.normals

    def sample(p):
        col = np.clip(np.rint((p[:, 0] - x0) / s).astype(int), 0, m.shape[1] - 1)
        row = np.clip(np.rint(h - 1 - (p[:, 1] - y0) / s).astype(int), 0, h - 1)
        return m[row, col]

    score = np.count_nonzero(sample(probe_in)) - np.count_nonzero(sample(probe_out))
    if score < 0:
        curve = Interface.polyline(pts[::-1], closed=curve.n_cells == curve.n_points, name=name)
    return curve


def _drop_floor(pts: np.ndarray, closed: bool, y_cut: float, name: str) -> tuple[np.ndarray, bool]:
    """Longest run of consecutive points with ``y > y_cut`` (an open curve)."""
    keep = pts[:, 1] > y_cut
    if keep.all():
        return pts, closed
    if not keep.any():
        raise _MaskError(f"{name}: the whole interface lies on the floor (y <= {y_cut:g} mm)")
    if closed:  # start right after a dropped point so runs do not wrap around
        shift = int(np.flatnonzero(~keep)[0]) + 1
        pts, keep = np.roll(pts, -shift, axis=0), np.roll(keep, -shift)
    edges = np.diff(np.r_[0, keep.astype(int), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    k = int(np.argmax(ends - starts))
    run = pts[starts[k] : ends[k]]
    if run.shape[0] < 2:
        raise _MaskError(f"{name}: less than 2 contour points above the floor y = {y_cut:g} mm")
    return run, False

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

Synthetic scans
---------------
:func:`render_scan` and :func:`segment_scan` go the other way, for benchmarks with
image data: an interface is drawn into an OCT-like intensity image (area-fraction
occupancy, Gaussian point-spread function, multiplicative speckle, additive noise)
which is then segmented into a mask as an analysis pipeline would (Gaussian
pre-smoothing, threshold, removal of small specks and holes); :func:`render_mask`
does both. The pixel grid uses the convention above.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayescalib.geometry.interface import Interface

__all__ = ["load_mask", "mask_contour", "read_mask", "pixel_grid", "render_mask", "render_scan",
           "segment_scan"]


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


def read_mask(path: str | Path, *, image: str = "auto",
              segmentation: dict | None = None) -> tuple[np.ndarray, dict]:
    """A biofilm mask from an image file, and what was done (``{"kind": "mask"}``)."""
    return load_mask(path), {"kind": "mask"}


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


# ------------------------------------------------------------------ synthetic scans
def pixel_grid(
    bounds: np.ndarray, pixel_size: float, margin: float = 0.0, floor: float | None = None
) -> tuple[tuple[int, int], tuple[float, float]]:
    """Image shape and origin covering a box with a margin.

    Parameters
    ----------
    bounds : array_like, shape (2, 2)
        ``[[xmin, ymin], [xmax, ymax]]`` in mm (e.g. :attr:`Interface.bounds`).
    pixel_size : float
        Pixel size ``s`` in mm (> 0).
    margin : float
        Extra space on every side, mm (>= 0); none below ``floor``.
    floor : float, optional
        y of the floor in mm: the bottom edge of the image is put on it, so the
        bottom row of pixels lies just above it (centres at ``floor + s/2``).

    Returns
    -------
    shape : (int, int)
        ``(H, W)`` pixels.
    origin : (float, float)
        Position (mm) of the centre of the bottom-left pixel.
    """
    b = np.asarray(bounds, dtype=float)
    s = float(pixel_size)
    if b.shape != (2, 2) or not np.isfinite(b).all() or np.any(b[1] < b[0]):
        raise ValueError(f"bounds must be [[xmin, ymin], [xmax, ymax]] in mm, got {b.tolist()}")
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"pixel size must be > 0 mm, got {pixel_size}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be >= 0 mm, got {margin}")
    x_lo, x_hi = b[0, 0] - margin, b[1, 0] + margin
    y_lo = b[0, 1] - margin if floor is None else float(floor)
    y_hi = b[1, 1] + margin
    w = int(np.ceil((x_hi - x_lo) / s))
    h = int(np.ceil((y_hi - y_lo) / s))
    return (max(h, 2), max(w, 2)), (float(x_lo + 0.5 * s), float(y_lo + 0.5 * s))


def _occupancy(points: np.ndarray, shape: tuple[int, int],
               pixel_size: float, origin: tuple[float, float], supersample: int) -> np.ndarray:
    """Area fraction of every pixel covered by the foreground (see :func:`render_scan`)."""
    from skimage.draw import polygon

    h, w = shape
    k = int(supersample)
    s = float(pixel_size)
    x0, y0 = float(origin[0]), float(origin[1])
    # (x, y) -> fractional indices of the k-times finer grid whose cell centres are integers
    cols = ((points[:, 0] - x0) / s + 0.5) * k - 0.5
    rows = ((h - 1 - (points[:, 1] - y0) / s) + 0.5) * k - 0.5
    fine = np.zeros((h * k, w * k), dtype=bool)
    rr, cc = polygon(rows, cols, shape=fine.shape)
    fine[rr, cc] = True
    # the polygon closes the curve by the chord from its last to its first point; with the
    # foreground on the right of the curve that polygon is traversed clockwise (in x, y);
    # a counter-clockwise one bounds background (e.g. a fluid-filled hole)
    x, y = points[:, 0], points[:, 1]
    signed_area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    if signed_area > 0:
        fine = ~fine
    return fine.reshape(h, k, w, k).mean(axis=(1, 3))


def render_scan(
    points: np.ndarray,
    *,
    pixel_size: float,
    origin: tuple[float, float],
    shape: tuple[int, int],
    rng: np.random.Generator,
    psf_sigma: float = 1.0,
    looks: float | None = 4.0,
    noise: float = 0.05,
    supersample: int = 8,
) -> np.ndarray:
    """OCT-like intensity image of a 2D interface (biofilm bright, fluid dark).

    The foreground is the region on the right of the curve (the convention of
    :mod:`bayescalib.geometry.interface`: normals point into the fluid); an open
    curve is closed by the chord from its last to its first point, which for a
    biofilm patch whose ends sit on the floor is the floor (a closed curve is given
    without repeating its first point). The image is

    ``I = (G_psf * a) * S + noise * N``,

    where ``a`` is the area fraction of each pixel inside the foreground (from a
    ``supersample``-times finer grid), ``G_psf`` a Gaussian of standard deviation
    ``psf_sigma`` pixels, ``S`` speckle: independent gamma-distributed intensity per
    pixel with mean 1 and ``looks`` looks (standard deviation ``1/sqrt(looks)``;
    ``looks = 1`` is fully developed speckle, exponential intensity), and ``N``
    standard normal noise per pixel. The fluid therefore has mean intensity 0 and
    the biofilm 1.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        The curve, ordered, in mm, foreground on its right.
    pixel_size : float
        Pixel size ``s`` in mm (> 0), e.g. 0.005 for 5 um.
    origin : (float, float)
        Position (mm) of the centre of the bottom-left pixel.
    shape : (int, int)
        ``(H, W)`` pixels (see :func:`pixel_grid`).
    rng : numpy.random.Generator
        Source of the speckle and the noise (seed it for a reproducible image).
    psf_sigma : float
        Standard deviation of the Gaussian point-spread function, pixels (>= 0).
    looks : float or None
        Speckle looks (> 0); None: no speckle.
    noise : float
        Standard deviation of the additive Gaussian noise, in units of the
        biofilm-fluid contrast (>= 0).
    supersample : int
        Sub-samples per pixel and axis for the area fraction (>= 1).

    Returns
    -------
    ndarray of float, shape (H, W)
        Intensity; row 0 is the top of the image.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3:
        raise ValueError(f"points must be an (n >= 3, 2) array in mm, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN/inf")
    h, w = (int(v) for v in shape)
    if h < 2 or w < 2:
        raise ValueError(f"shape must be at least (2, 2) pixels, got {shape}")
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise ValueError(f"pixel_size must be > 0 mm, got {pixel_size}")
    if not (np.isfinite(psf_sigma) and psf_sigma >= 0):
        raise ValueError(f"psf_sigma must be >= 0 pixels, got {psf_sigma}")
    if looks is not None and not (np.isfinite(looks) and looks > 0):
        raise ValueError(f"looks must be > 0 (or None for no speckle), got {looks}")
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be >= 0, got {noise}")
    if int(supersample) < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    from scipy.ndimage import gaussian_filter

    img = _occupancy(pts, (h, w), float(pixel_size), origin, int(supersample))
    if psf_sigma > 0:
        img = gaussian_filter(img, float(psf_sigma), mode="nearest")
    if looks is not None:
        img = img * rng.gamma(float(looks), 1.0 / float(looks), size=img.shape)
    if noise > 0:
        img = img + float(noise) * rng.standard_normal(img.shape)
    return img


def segment_scan(
    image: np.ndarray,
    *,
    smooth: float = 1.0,
    threshold: float | str = 0.5,
    min_size: int = 16,
) -> np.ndarray:
    """Segment an intensity image into a biofilm mask.

    Parameters
    ----------
    image : ndarray of float, shape (H, W)
        Intensity (e.g. from :func:`render_scan`).
    smooth : float
        Standard deviation of a Gaussian pre-filter, pixels (>= 0; 0 = none): it
        averages the speckle so the threshold does not riddle the biofilm with holes.
    threshold : float or "otsu"
        Intensity threshold (0.5 is half the contrast of :func:`render_scan`), or
        Otsu's threshold of the smoothed image.
    min_size : int
        Connected foreground specks and background holes smaller than this many
        pixels are removed (0 = keep all).

    Returns
    -------
    ndarray of bool, shape (H, W)
        Foreground (biofilm) True.
    """
    from scipy.ndimage import gaussian_filter, label

    img = np.asarray(image, dtype=float)
    if img.ndim != 2:
        raise ValueError(f"image must be 2D, got shape {img.shape}")
    if not np.isfinite(img).all():
        raise ValueError("image contains NaN/inf")
    if not (np.isfinite(smooth) and smooth >= 0):
        raise ValueError(f"smooth must be >= 0 pixels, got {smooth}")
    if int(min_size) < 0:
        raise ValueError(f"min_size must be >= 0 pixels, got {min_size}")
    if smooth > 0:
        img = gaussian_filter(img, float(smooth), mode="nearest")
    if isinstance(threshold, str):
        if threshold != "otsu":
            raise ValueError(f"threshold must be a number or 'otsu', got {threshold!r}")
        from skimage.filters import threshold_otsu

        t = float(threshold_otsu(img))
    else:
        t = float(threshold)
    mask = img > t
    if min_size > 0:
        for value in (True, False):  # specks of foreground, then holes in it
            lab, n = label(mask == value)
            if n > 1:
                sizes = np.bincount(lab.ravel())
                small = np.flatnonzero(sizes < int(min_size))
                small = small[small > 0]
                mask[np.isin(lab, small)] = not value
    return mask


def render_mask(
    points: np.ndarray,
    *,
    pixel_size: float,
    origin: tuple[float, float],
    shape: tuple[int, int],
    rng: np.random.Generator,
    psf_sigma: float = 1.0,
    looks: float | None = 4.0,
    noise: float = 0.05,
    smooth: float = 1.0,
    threshold: float | str = 0.5,
    min_size: int = 16,
    supersample: int = 8,
) -> np.ndarray:
    """Segmented mask of a 2D interface: :func:`render_scan` then :func:`segment_scan`.

    Parameters are those of the two functions (pixel size and origin in mm, the
    point-spread function and the smoothing in pixels). Returns a boolean array of
    shape ``shape``, foreground (biofilm) True, which :func:`mask_contour` with the
    same ``pixel_size`` and ``origin`` turns back into the interface.
    """
    img = render_scan(points, pixel_size=pixel_size, origin=origin, shape=shape, rng=rng,
                      psf_sigma=psf_sigma, looks=looks, noise=noise,
                      supersample=supersample)
    return segment_scan(img, smooth=smooth, threshold=threshold, min_size=min_size)

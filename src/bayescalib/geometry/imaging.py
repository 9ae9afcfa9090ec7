"""Interface extraction from an image: a binary mask, or a raw greyscale scan that is
segmented here.

The observed interface is the 0.5 iso-line of the mask (foreground = biofilm,
value 1; background = fluid, value 0), traced with sub-pixel accuracy by
marching squares (:func:`skimage.measure.find_contours`); its points lie on
pixel edges, linearly interpolated, so a disc of radius R pixels is recovered
to well below one pixel.

Reading an image file (:func:`read_mask`)
-----------------------------------------
:func:`read_mask` is the one entry point that turns any image file (PNG or TIFF;
8-bit, 16-bit, float or boolean greyscale; RGB/RGBA use their first channel) into a
boolean mask, row 0 at the top, True = biofilm, and says how in an info dict:

1. *Size guard.* The header is read first (Pillow, without decoding the pixels):
   an image of more than :data:`MAX_IMAGE_PIXELS` pixels is refused before it is
   decoded (a decompression bomb or a wrong file would take the memory of the job).
2. *Mask or scan.* ``image="auto"``: an image with exactly two distinct grey values
   is a mask (foreground = the brighter value), any other is a raw scan (e.g. an
   OCT B-scan: biofilm bright, fluid dark). A single grey value (all black or all
   white) is refused: there is nothing to trace.
3. *Segmentation of a scan* (:func:`segment_scan`, the only segmentation function):
   Gaussian pre-filter of standard deviation ``smooth`` pixels (it averages the
   speckle), a threshold in the image's own intensity scale (a number, or Otsu's
   threshold of the smoothed image), then foreground specks and background holes
   smaller than ``min_size`` pixels are removed. A segmentation with no foreground
   or no background is refused. Which part of the mask becomes the interface is
   decided by :func:`mask_contour` as for any mask (the longest contour: the main
   colony).
4. *Floor* (``info["floor"]``; used when ``floor: auto``): the substrate line,
   found in this order, the first that applies:

   a. *bright band* (scans only): the row with the highest median intensity across
      the columns (of the smoothed scan) spans the width (foreground in at least
      :data:`FLOOR_FULL_WIDTH` of the columns) and is brighter than the biofilm
      (its median exceeds the background level by at least :data:`FLOOR_BRIGHT`
      times the biofilm's contrast): the specular reflection of the flow-cell floor
      in OCT. The floor is the top edge of that band (where the row median falls to
      half-way between the band's peak and the biofilm level);
   b. *full-width band*: the lowest run of rows that are foreground across the
      width, when it is thin (at most :data:`FLOOR_MAX_BAND` of the height, at
      least 3 rows) and there is foreground above it (colonies on a substrate
      segmented as foreground). Its top edge;
   c. *foreground bottom*: the bottom edge of the lowest foreground row (colonies
      above a substrate segmented as background); when that is the image's last
      row (the floor is the bottom edge of the image) nothing is cut
      (``method = "image bottom"``).

   Rule (a) needs the substrate to be brighter than the biofilm (it usually is in
   OCT); rule (b) cannot tell a thin continuous film lying on the floor from a
   substrate line, and a rough film whose valleys reach such a band is cut there:
   give ``floor`` as a number when the overlay figure shows the wrong line. Rows
   are image rows; ``row`` is the edge position, e.g. 187.5 for the edge between
   rows 187 and 188.
5. *Segmentation uncertainty* (scans): the interface traced from the mask carries
   two errors of its own, independent of the model. (i) Noise: the threshold
   crossing of the smoothed image ``I_s`` moves by ``dn = delta_I / |grad I_s|``
   when the intensity at the crossing is perturbed by ``delta_I``, so its standard
   deviation is ``sigma_noise = sigma_s / |grad I_s|`` (first order, the classic
   edge-localisation result), where ``sigma_s = k * sigma_I`` is the noise of the
   smoothed image (``k`` the root sum of squares of the discrete Gaussian kernel,
   exact for pixel-independent noise) and ``sigma_I`` the pixel noise at the
   threshold level. ``sigma_I`` is estimated from the raw image on both sides of
   the contour, 3 to 8 pixels away from it (no edge in the estimator's 3 x 3
   support), with Immerkaer's Laplacian-difference estimator (robust: MAD), and
   interpolated linearly in intensity between the fluid side and the biofilm side
   to the threshold (OCT speckle is multiplicative, so the noise grows with the
   intensity). The gradient is the central difference of ``I_s`` at the pixels on
   both sides of the mask boundary, and ``sigma_noise`` the median over them.
   (ii) Quantisation: the traced nodes of a binary mask lie on pixel edges, so the
   crossing is rounded to the nearest edge, an error uniform over one pixel
   (sd ``1/sqrt(12)`` pixel). ``info["sigma_px"]`` is
   ``sqrt(sigma_noise^2 + 1/12)`` pixels. Noise correlated between pixels (speckle
   grains larger than a pixel) is averaged less by the pre-filter than assumed, so
   the value is a lower bound of the noise part; the diagnosis uses it as such
   (:mod:`bayescalib.diagnosis.residuals`). Masks carry no intensity: no value.

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

from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface

__all__ = ["FLOOR_BRIGHT", "FLOOR_FULL_WIDTH", "FLOOR_MAX_BAND", "MAX_IMAGE_PIXELS",
           "ImageError", "find_floor", "image_size", "inverted", "load_mask", "mask_contour", "pixel_grid", "read_image", "read_mask",
           "render_mask", "render_scan", "segment_scan", "segmentation_options"]

#: largest image (pixels, width x height) that is decoded: 50 megapixels, ~100 times an
#: OCT B-scan; the header is checked before any pixel is decoded
MAX_IMAGE_PIXELS = 50_000_000
#: a row "spans the width" when at least this share of its pixels is foreground
FLOOR_FULL_WIDTH = 0.9
#: a bright band is brighter than the biofilm: its row median exceeds the background
#: level by at least this many times the biofilm's contrast (biofilm minus background)
FLOOR_BRIGHT = 1.25
#: the thickest full-width band taken for a substrate line, as a share of the height
FLOOR_MAX_BAND = 0.05
#: distance from the contour (pixels) of the pixels that estimate the noise
_NOISE_RING = (3, 8)


class ImageError(ValueError):
    """An image that cannot become a mask; the message names the file and the problem."""


_MaskError = ImageError  # the former name (callers catch it)


def image_size(path: str | Path) -> tuple[int, int]:
    """``(width, height)`` of an image from its header, without decoding the pixels.

    Raises
    ------
    ImageError
        When no header can be read (not an image, truncated, unknown format).
    """
    import re
    import warnings

    from PIL import Image

    p = Path(path)
    try:
        with warnings.catch_warnings():  # Pillow warns above 89 megapixels: judged below
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as im:
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as exc:  # Pillow's own limit, ~179 megapixels
        n = re.search(r"\((\d+) pixels\)", str(exc))
        size = f"{int(n.group(1)) / 1e6:.1f} megapixels" if n else "too many pixels"
        raise ImageError(f"{p}: the image header declares {size}, more than the limit of "
                         f"{MAX_IMAGE_PIXELS / 1e6:g} megapixels: refused before decoding "
                         "(crop the region of interest, or check that this is the right "
                         "file)") from None
    except Exception as exc:  # noqa: BLE001 - Pillow raises many kinds on a broken file
        if p.suffix.lower() in (".tif", ".tiff"):  # TIFF variants Pillow does not know
            try:
                import tifffile

                with tifffile.TiffFile(p) as tf:
                    shape = tf.pages[0].shape
                h, w = (int(v) for v in shape[:2])
                return w, h
            except Exception:  # noqa: BLE001, S110 - no readable header: the error below
                pass
        raise ImageError(f"{p}: cannot read the image header ({type(exc).__name__}: {exc})") from None


@cache
def _segmentation_defaults() -> dict[str, Any]:
    from bayescalib.config import schema

    props = schema("measures")["definitions"]["observation_file"]["properties"]
    return {k: v["default"] for k, v in props["segmentation"]["properties"].items()}


def segmentation_options(segmentation: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The segmentation settings with the schema's defaults filled in
    (``measures.schema.yaml#/definitions/observation_file/properties/segmentation``):
    ``smooth`` (pixels), ``threshold`` (image intensity or ``"otsu"``), ``min_size``
    (pixels). Unknown keys raise ValueError."""
    opts = dict(_segmentation_defaults())
    extra = set(segmentation or {}) - set(opts)
    if extra:
        raise ValueError(f"unknown segmentation setting(s) {sorted(extra)}; known: {sorted(opts)}")
    opts.update({k: v for k, v in (segmentation or {}).items() if v is not None})
    return opts


def read_image(path: str | Path, max_pixels: int = MAX_IMAGE_PIXELS
               ) -> tuple[np.ndarray, dict[str, Any]]:
    """The grey values of an image file, after the header's size check (the first
    channel of a colour image).

    Returns
    -------
    image : ndarray of float, shape (H, W)
        Grey values in the file's own scale; row 0 is the top.
    info : dict
        ``shape`` [H, W], ``bit_depth``, ``dtype``, ``channels``.

    Raises
    ------
    ImageError
        Naming the file: unreadable, above ``max_pixels``, not 2D, NaN/inf.
    """
    return _decode(Path(path), max_pixels)


def _decode(p: Path, max_pixels: int) -> tuple[np.ndarray, dict[str, Any]]:
    """Pixels of the first channel as a 2D array, after the header's size check."""
    from skimage import io

    w, h = image_size(p)
    if w * h > int(max_pixels):
        raise ImageError(
            f"{p}: the image is {w} x {h} pixels ({w * h / 1e6:.1f} megapixels), more than "
            f"the limit of {int(max_pixels) / 1e6:g} megapixels: refused before decoding "
            "(crop the region of interest, or check that this is the right file)")
    try:
        img = np.asarray(io.imread(str(p)))
    except Exception as exc:  # noqa: BLE001 - decoders raise anything on a broken file
        raise ImageError(f"{p}: cannot read the image ({type(exc).__name__}: {exc})") from None
    channels = 1
    if img.ndim == 3 and img.shape[-1] <= 4:
        channels = int(img.shape[-1])
        img = img[..., 0]
    if img.ndim != 2:
        raise ImageError(f"{p}: expected a 2D image (greyscale, or RGB/RGBA: the first "
                         f"channel is used), got an array of shape {img.shape}")
    if img.dtype == bool:
        depth = 1
    elif np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating):
        depth = int(img.dtype.itemsize * 8)
    else:
        raise ImageError(f"{p}: unsupported pixel type {img.dtype}")
    fimg = img.astype(float)
    if not np.isfinite(fimg).all():
        raise ImageError(f"{p}: the image contains NaN/inf values")
    return fimg, {"shape": [int(img.shape[0]), int(img.shape[1])], "bit_depth": depth,
                  "dtype": str(img.dtype), "channels": channels}


def load_mask(path: str | Path) -> np.ndarray:
    """Read a PNG/TIFF mask as a boolean array (foreground = value above the midpoint
    of its lowest and highest value); any image is taken as a mask. See :func:`read_mask`,
    which also segments raw scans."""
    return read_mask(path, image="mask")[0]


def read_mask(
    path: str | Path,
    *,
    image: str = "auto",
    segmentation: Mapping[str, Any] | None = None,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Any image file as a boolean biofilm mask (see the module docstring).

    Parameters
    ----------
    path : str or Path
        PNG or TIFF; greyscale (8-, 16-bit, float, boolean) or RGB/RGBA (first channel).
    image : {"auto", "mask", "scan"}
        ``mask``: foreground = above the midpoint of the lowest and highest value;
        ``scan``: segmented (:func:`segment_scan`); ``auto``: a mask when the image has
        exactly two distinct values, else a scan.
    segmentation : mapping, optional
        Scan settings ``smooth`` (pixels), ``threshold`` (in the image's intensity
        scale, or ``"otsu"``), ``min_size`` (pixels); missing ones take the schema's
        defaults (:func:`segmentation_options`).
    max_pixels : int
        Largest image decoded (pixels); the header is checked first.

    Returns
    -------
    mask : ndarray of bool, shape (H, W)
        True = biofilm; row 0 is the top of the image.
    info : dict
        ``path``, ``kind`` (``"mask"``/``"scan"``), ``shape`` [H, W], ``bit_depth``,
        ``dtype``, ``channels``, ``threshold`` (image intensity), ``threshold_method``
        (``"otsu"``, ``"given"``, ``"midpoint"`` for masks), ``smooth_px``,
        ``min_size_px``, ``foreground_fraction``, ``top_foreground`` (the share of the
        top row that is foreground: see :func:`inverted`), ``floor`` (``method``, ``row``: the
        edge position in rows, None for ``"image bottom"``), and for scans the
        segmentation uncertainty: ``sigma_px`` (total), ``sigma_noise_px``,
        ``sigma_quantisation_px``, ``noise_sd`` (pixel noise at the threshold, image
        intensity), ``gradient`` (median ``|grad I_s|`` at the contour, intensity per
        pixel); None for masks.

    Raises
    ------
    ImageError
        Naming the file: unreadable, too large, not 2D, a single grey value, or a
        segmentation without foreground or without background.
    """
    p = Path(path)
    if image not in ("auto", "mask", "scan"):
        raise ValueError(f"{p}: image must be 'auto', 'mask' or 'scan', got {image!r}")
    img, info = _decode(p, max_pixels)
    info = {"path": str(p), **info}
    lo, hi = float(img.min()), float(img.max())
    if lo == hi:
        raise ImageError(f"{p}: the image has a single grey value ({lo:g}: all black or all "
                         "white): nothing to segment")
    kind = image
    if kind == "auto":
        kind = "mask" if np.unique(img).size == 2 else "scan"
    sigma: dict[str, Any] = {"sigma_px": None, "sigma_noise_px": None,
                             "sigma_quantisation_px": None, "noise_sd": None, "gradient": None}
    smoothed = None
    if kind == "mask":
        t = 0.5 * (lo + hi)
        mask = img > t
        seg = {"threshold": t, "threshold_method": "midpoint", "smooth_px": None,
               "min_size_px": None}
    else:
        opts = segmentation_options(segmentation)
        try:
            mask, smoothed, t = _segment(img, smooth=float(opts["smooth"]),
                                         threshold=opts["threshold"],
                                         min_size=int(opts["min_size"]))
        except ValueError as exc:
            raise ImageError(f"{p}: segmentation: {exc}") from None
        seg = {"threshold": t,
               "threshold_method": "otsu" if opts["threshold"] == "otsu" else "given",
               "smooth_px": float(opts["smooth"]), "min_size_px": int(opts["min_size"])}
        where = f"(threshold {t:.6g} in the image's intensity range {lo:g} to {hi:g}, " \
                f"{seg['threshold_method']})"
        if not mask.any():
            raise ImageError(f"{p}: the segmentation of the scan finds no foreground "
                             f"(biofilm) {where}")
        if mask.all():
            raise ImageError(f"{p}: the segmentation of the scan finds no background "
                             f"(fluid) {where}")
        sigma = _positional_sigma(img, smoothed, mask, float(opts["smooth"]))
    info.update(kind=kind, **seg, foreground_fraction=float(mask.mean()),
                top_foreground=float(mask[0].mean()),
                floor=find_floor(mask, smoothed, float(seg["smooth_px"] or 0.0), t), **sigma)
    return mask, info


def inverted(info: Mapping[str, Any]) -> str | None:
    """Why a mask read by :func:`read_mask` looks inverted, or None.

    A colony on the floor of a flow cell has fluid above it: an image whose foreground
    (the brighter value of a mask, the bright part of a scan) fills the top row across
    the width (at least :data:`FLOOR_FULL_WIDTH` of it) has the fluid bright and the
    biofilm dark, or a threshold below the fluid's level. The callers that model such
    a colony (the fsi model's scan and its 2D observations) refuse it; a generic edge
    or a film on a channel's ceiling is no error of :func:`read_mask` itself.

    Parameters
    ----------
    info : mapping
        The info dict of :func:`read_mask`.

    Returns
    -------
    str or None
        The reason, in words, starting with the file's path.
    """
    top = info.get("top_foreground")
    if top is None or top < FLOOR_FULL_WIDTH:
        return None
    scan = info.get("kind") == "scan"
    return (f"{info['path']}: the foreground (the {'bright part' if scan else 'brighter value'}"
            f", taken for biofilm) fills {100 * top:.0f} % of the image's top row: the fluid "
            "above the colony must be the dark part and the biofilm the bright one. This "
            "looks like an inverted image (fluid bright, biofilm dark): invert its grey "
            "values" + (" (or check segmentation.threshold)" if scan else ""))


def find_floor(mask: np.ndarray, smoothed: np.ndarray | None = None,
               blur: float = 0.0, threshold: float | None = None) -> dict[str, Any]:
    """The substrate line of a mask (and its smoothed scan), rules (a)-(c) of the module
    docstring.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
        True = biofilm (and substrate, where it was segmented as foreground).
    smoothed : ndarray of float, shape (H, W), optional
        The smoothed scan (enables rule (a)).
    blur : float
        Pre-filter sd of the scan, pixels (with the point-spread function, the bright
        band's blur reaches up to ``ceil(3 blur) + 3`` rows above its edge).
    threshold : float, optional
        The segmentation threshold (rule (a): the band's halo is the rows above its
        edge where the fluid columns' median intensity exceeds half-way from the
        background level to the threshold; the floor is put on the halo's top, so the
        contour that the halo's speckle makes there is cut too).

    Returns
    -------
    dict
        ``method`` (``"bright band"``, ``"full-width band"``, ``"foreground bottom"``,
        ``"image bottom"``) and ``row``: the floor's edge position in image rows
        (half-integer: between two rows; None for ``"image bottom"``), where the
        contour is cut. A bright band adds ``edge_row``: its own top edge (at half its
        height above the biofilm), the substrate's surface, below ``row`` by the halo.
    """
    m = np.asarray(mask, dtype=bool)
    h = m.shape[0]
    cover = m.mean(axis=1)
    full = cover >= FLOOR_FULL_WIDTH
    if smoothed is not None and m.any() and (~m).any():
        prof = np.median(smoothed, axis=1)
        partial = m & ~full[:, None]
        film = float(np.median(smoothed[partial if partial.any() else m]))
        back = float(np.median(smoothed[~m]))
        r = int(np.argmax(prof))
        if full[r] and film > back and prof[r] - back >= FLOOR_BRIGHT * (film - back):
            half = 0.5 * (prof[r] + film)
            top = r
            while top > 0 and prof[top - 1] > half:
                top -= 1
            edge = top - 0.5  # the band's top edge: half-way from the biofilm to its peak
            # the band's blurred halo, partly segmented as foreground: the contour runs on it
            reach = top - (int(np.ceil(3.0 * blur)) + 3)
            fluid = ~m[max(reach - 1, 0)]
            if threshold is not None and fluid.mean() >= 0.05:
                halo = np.median(smoothed[:, fluid], axis=1)
                level = back + 0.5 * (float(threshold) - back)
                while top > 0 and top - 1 >= reach and halo[top - 1] > level:
                    top -= 1
            return {"method": "bright band", "row": top - 0.5, "edge_row": edge}
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        return {"method": "image bottom", "row": None}
    fr = np.flatnonzero(full)
    if fr.size:
        bottom = int(fr[-1])
        top = bottom
        while top > 0 and full[top - 1]:
            top -= 1
        thin = bottom - top + 1 <= max(3, int(FLOOR_MAX_BAND * h))
        if thin and rows[0] < top:
            return {"method": "full-width band", "row": top - 0.5}
    low = int(rows[-1])
    if low == h - 1:
        return {"method": "image bottom", "row": None}
    return {"method": "foreground bottom", "row": low + 0.5}


def _immerkaer(img: np.ndarray, where: np.ndarray) -> float | None:
    """Pixel noise sd from the Laplacian-difference kernel (Immerkaer 1996), robust
    (MAD) over the pixels ``where`` (at least 30), else None."""
    from scipy.ndimage import convolve

    k = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
    resp = convolve(img, k, mode="nearest")
    inner = np.zeros_like(where)
    inner[1:-1, 1:-1] = where[1:-1, 1:-1]
    v = resp[inner]
    if v.size < 30:
        return None
    return float(1.4826 * np.median(np.abs(v - np.median(v))) / 6.0)


def _positional_sigma(img: np.ndarray, smoothed: np.ndarray, mask: np.ndarray,
                      smooth: float) -> dict[str, Any]:
    """Segmentation uncertainty of a scan's interface (module docstring, item 5), pixels."""
    from scipy.ndimage import distance_transform_edt, gaussian_filter

    quant = float(1.0 / np.sqrt(12.0))
    d_in = distance_transform_edt(mask)
    d_out = distance_transform_edt(~mask)
    a, b = _NOISE_RING
    sides = []
    for inside, dist in ((False, d_out), (True, d_in)):
        ring = (dist >= a) & (dist <= b)
        if np.count_nonzero(ring) < 30:
            ring = dist >= 1  # a thin layer: the whole side
        sides.append((_immerkaer(img, ring), float(np.median(img[ring])) if ring.any() else None))
    (n_f, m_f), (n_b, m_b) = sides
    # the threshold of the smoothed image, interpolated on the raw intensity scale
    t = float(np.median(smoothed[(d_in == 1) | (d_out == 1)]))
    known = [(n, m) for n, m in sides if n is not None and m is not None]
    if not known:
        return {"sigma_px": None, "sigma_noise_px": None, "sigma_quantisation_px": quant,
                "noise_sd": None, "gradient": None}
    if len(known) == 2 and m_b != m_f:
        w = float(np.clip((t - m_f) / (m_b - m_f), 0.0, 1.0))
        noise = (1.0 - w) * n_f + w * n_b
    else:
        noise = float(np.mean([n for n, _ in known]))
    if smooth > 0:
        r = int(np.ceil(4.0 * smooth)) + 1
        delta = np.zeros((2 * r + 1, 2 * r + 1))
        delta[r, r] = 1.0
        gain = float(np.sqrt(np.sum(gaussian_filter(delta, smooth, mode="constant") ** 2)))
    else:
        gain = 1.0
    gy, gx = np.gradient(smoothed)
    g = np.hypot(gx, gy)[(d_in == 1) | (d_out == 1)]
    g = g[g > 0]
    if g.size == 0:
        return {"sigma_px": None, "sigma_noise_px": None, "sigma_quantisation_px": quant,
                "noise_sd": noise, "gradient": 0.0}
    s_noise = float(np.median(noise * gain / g))
    return {"sigma_px": float(np.hypot(s_noise, quant)), "sigma_noise_px": s_noise,
            "sigma_quantisation_px": quant, "noise_sd": float(noise),
            "gradient": float(np.median(g))}


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
    from bayescalib.geometry.outline import signed_area

    if signed_area(points) > 0:
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
        Intensity (e.g. from :func:`render_scan`, or a raw scan in its own scale).
    smooth : float
        Standard deviation of a Gaussian pre-filter, pixels (>= 0; 0 = none): it
        averages the speckle so the threshold does not riddle the biofilm with holes.
    threshold : float or "otsu"
        Intensity threshold in the image's scale (0.5 is half the contrast of
        :func:`render_scan`), or Otsu's threshold of the smoothed image.
    min_size : int
        Connected foreground specks and background holes smaller than this many
        pixels are removed (0 = keep all).

    Returns
    -------
    ndarray of bool, shape (H, W)
        Foreground (biofilm) True.
    """
    return _segment(image, smooth=smooth, threshold=threshold, min_size=min_size)[0]


def _segment(image: np.ndarray, *, smooth: float, threshold: float | str,
             min_size: int) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`segment_scan`, also returning the smoothed image and the threshold used."""
    from scipy.ndimage import gaussian_filter, label

    img = np.asarray(image, dtype=float)
    if img.ndim not in (2, 3):  # a 3D volume: bayescalib.geometry.volume
        raise ValueError(f"image must be 2D (or a 3D volume), got shape {img.shape}")
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

        t = float(threshold_otsu(img)) if np.ptp(img) > 0 else float(img.flat[0])
    else:
        t = float(threshold)
        if not np.isfinite(t):
            raise ValueError(f"threshold must be finite, got {threshold}")
    mask = img > t
    if min_size > 0:
        for value in (True, False):  # specks of foreground, then holes in it
            lab, n = label(mask == value)
            if n > 1:
                sizes = np.bincount(lab.ravel())
                small = np.flatnonzero(sizes < int(min_size))
                small = small[small > 0]
                mask[np.isin(lab, small)] = not value
    return mask, img, t


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

"""How the observed interfaces were segmented from their images.

* :func:`plot_segmentation` -- one panel per image observation: the image in grey
  (a raw scan as recorded, a mask as it is), the interface traced from it (colour),
  the floor it was cut at (dashed), in mm with the image's own pixel grid (pixel
  ``(row, col)`` centred at ``x = x0 + col * s``, ``y = y0 + (H - 1 - row) * s``,
  :mod:`bayescalib.geometry.imaging`). The panel title gives the snapshot, the pixel
  size, the threshold and how it was chosen, and the segmentation's positional
  uncertainty when known. A misplaced threshold (the contour inside the biofilm or
  out in the speckle of the fluid), a wrong floor or a wrong origin (the contour on
  the image but the axes off the flow cell) are seen at a glance.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ._validation import PathsLike, as_paths, as_points, finish
from .style import OKABE_ITO, paper_style

__all__ = ["plot_segmentation"]

#: colour of the traced interface and of the floor line (Okabe-Ito orange, sky blue)
INTERFACE_COLOR = OKABE_ITO[1]
FLOOR_COLOR = OKABE_ITO[2]


def _title(label: str, pixel_size: float, threshold: float | None, method: str | None,
           sigma: float | None) -> str:
    um = 1e3 * float(pixel_size)
    parts = [f"{label}: pixel {um:.3g} µm"]
    if threshold is not None:
        parts.append(f"threshold {threshold:.4g}" + (f" ({method})" if method else ""))
    if sigma is not None:
        parts.append(f"σ_seg {1e3 * sigma:.2g} µm")
    return ", ".join(parts)


def plot_segmentation(
    images: Sequence[np.ndarray],
    interfaces: Sequence[np.ndarray],
    paths: PathsLike,
    *,
    pixel_sizes: Sequence[float],
    origins: Sequence[Sequence[float]],
    floors: Sequence[float | None] | None = None,
    labels: Sequence[str] | None = None,
    thresholds: Sequence[float | None] | None = None,
    threshold_methods: Sequence[str | None] | None = None,
    sigmas: Sequence[float | None] | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Images with the interfaces traced from them, one panel each.

    Parameters
    ----------
    images : list of array_like, shape (H_k, W_k)
        Grey values in the image's own scale (row 0 at the top).
    interfaces : list of array_like, shape (n_k, 2)
        The interface traced from each image, mm.
    paths : path or sequence of paths
        Output files; format from the suffix.
    pixel_sizes : list of float
        Pixel size of each image, mm (> 0).
    origins : list of (float, float)
        Position of the centre of each image's bottom-left pixel, mm.
    floors : list of float or None, optional
        y of the floor each interface was cut at, mm (None: none).
    labels : list of str, optional
        Snapshot labels (default ``image 0``, ``image 1``, ...).
    thresholds : list of float or None, optional
        Threshold used, in the image's grey values (None: not shown).
    threshold_methods : list of str or None, optional
        How each threshold was chosen (``otsu``, ``given``, ``midpoint``).
    sigmas : list of float or None, optional
        Segmentation positional uncertainty of each interface, mm (None: not shown).
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    n = len(images)
    if n == 0:
        raise ValueError("images: at least one image is needed")
    imgs = []
    for k, im in enumerate(images):
        a = np.asarray(im, dtype=float)
        if a.ndim != 2 or min(a.shape) < 1 or not np.isfinite(a).all():
            raise ValueError(f"images[{k}]: a finite 2-D array is needed, got shape {a.shape}")
        imgs.append(a)
    curves = [as_points(c, f"interfaces[{k}]", allow_empty=False) for k, c in enumerate(interfaces)]

    def per(values, name, default):
        if values is None:
            return [default] * n
        if len(values) != n:
            raise ValueError(f"{name}: {len(values)} value(s) for {n} image(s)")
        return list(values)

    if len(curves) != n:
        raise ValueError(f"interfaces: {len(curves)} curve(s) for {n} image(s)")
    sizes = [float(v) for v in per(pixel_sizes, "pixel_sizes", None)]
    if not all(np.isfinite(s) and s > 0 for s in sizes):
        raise ValueError(f"pixel_sizes: must be > 0 mm, got {sizes}")
    orgs = [tuple(float(v) for v in o) for o in per(origins, "origins", None)]
    if not all(len(o) == 2 and np.isfinite(o).all() for o in orgs):
        raise ValueError(f"origins: (x, y) in mm per image, got {orgs}")
    flo = per(floors, "floors", None)
    lab = per(labels, "labels", None)
    lab = [f"image {k}" if v is None else str(v) for k, v in enumerate(lab)]
    thr = per(thresholds, "thresholds", None)
    how = per(threshold_methods, "threshold_methods", None)
    sig = per(sigmas, "sigmas", None)
    out_paths = as_paths(paths)

    with paper_style():
        width = 6.5
        heights = [float(np.clip(width * a.shape[0] / max(a.shape[1], 1), 1.0, 4.0))
                   for a in imgs]
        fig = Figure(figsize=(width, sum(heights) + 0.9 * n + 0.6), layout="constrained")
        axes = fig.subplots(n, 1, squeeze=False, height_ratios=heights)[:, 0]
        for k, ax in enumerate(axes):
            a, s, (x0, y0) = imgs[k], sizes[k], orgs[k]
            h, w = a.shape
            extent = (x0 - 0.5 * s, x0 + (w - 0.5) * s, y0 - 0.5 * s, y0 + (h - 0.5) * s)
            lo, hi = np.percentile(a, [0.5, 99.5])
            ax.imshow(a, cmap="gray", extent=extent, origin="upper", interpolation="nearest",
                      vmin=lo, vmax=hi if hi > lo else lo + 1.0, aspect="equal")
            c = curves[k]
            ax.plot(c[:, 0], c[:, 1], color=INTERFACE_COLOR, lw=1.0, zorder=3)
            if flo[k] is not None:
                ax.axhline(float(flo[k]), color=FLOOR_COLOR, ls="--", lw=0.9, zorder=2)
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
            ax.set_title(_title(lab[k], s, thr[k], how[k], sig[k]), fontsize=8, loc="left")
            ax.set_ylabel("y [mm]")
        axes[-1].set_xlabel("x [mm]")
        handles = [Line2D([], [], color=INTERFACE_COLOR, lw=1.2, label="traced interface")]
        if any(v is not None for v in flo):
            handles.append(Line2D([], [], color=FLOOR_COLOR, ls="--", lw=1.0,
                                  label="floor (cut)"))
        fig.legend(handles=handles, loc="outside lower center", ncols=len(handles),
                   frameon=False)
        return finish(fig, out_paths, dpi, return_figure)

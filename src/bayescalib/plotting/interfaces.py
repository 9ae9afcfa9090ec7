"""Fluid-biofilm interface curves and scalar fields along the interface.

* :func:`plot_interfaces` -- undeformed interface (grey dashed), observed
  interface(s) (black), interfaces of posterior samples (thin, transparent),
  optional MAP interface, equal aspect in mm, with a zoom panel on the region
  of largest deformation (paper Fig. "contoursamples").
* :func:`plot_interface_residual` -- interface coloured by a signed scalar
  (e.g. standardized residuals) with a diverging colormap centred at zero,
  for model-form diagnosis.

Interfaces are open or closed polylines given as ordered (n, 2) point arrays.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ._checks import PathsLike, as_array, as_paths, as_points, finish
from .style import COLORS, DIVERGING_CMAP, paper_style

__all__ = ["largest_deformation_box", "plot_interface_residual", "plot_interfaces"]


def _as_curve_list(curves, name: str) -> list[np.ndarray]:
    if curves is None:
        return []
    if isinstance(curves, np.ndarray) and curves.ndim == 2:
        curves = [curves]
    out = []
    for k, c in enumerate(curves):
        a = as_points(c, f"{name}[{k}]", allow_empty=False)
        if a.shape[0] < 2:
            raise ValueError(f"{name}[{k}]: an interface needs at least 2 points")
        out.append(a)
    return out


def _min_dist(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 2) to the polyline ``curve`` (m, 2)."""
    a, b = curve[:-1], curve[1:]
    ab = b - a
    len2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip(np.sum(ap * ab[None], axis=2) / len2[None], 0.0, 1.0)
    proj = a[None] + t[..., None] * ab[None]
    return np.sqrt(np.min(np.sum((points[:, None, :] - proj) ** 2, axis=2), axis=1))


def largest_deformation_box(reference: np.ndarray, deformed: np.ndarray,
                            others: Sequence[np.ndarray] = (), rel_width: float = 0.2,
                            ) -> tuple[float, float, float, float]:
    """Rectangle around the point of ``deformed`` farthest from ``reference``.

    Parameters
    ----------
    reference : numpy.ndarray, shape (n, 2)
        Undeformed interface.
    deformed : numpy.ndarray, shape (m, 2)
        Deformed interface.
    others : sequence of (k, 2) arrays
        Further curves that should fit vertically into the box.
    rel_width : float
        Half-width of the box as a fraction of the x extent of both curves;
        at least three times the maximal deformation.

    Returns
    -------
    (x0, x1, y0, y1) : tuple of float
        Box limits in the curves' units: the x window is centred at the point
        of largest deformation, the y window spans all curve points inside the
        x window (padded by 15 %).
    """
    dist = _min_dist(deformed, reference)
    k = int(np.argmax(dist))
    c = deformed[k]
    near = reference[np.argmin(np.sum((reference - c) ** 2, axis=1))]
    cx = 0.5 * (c[0] + near[0])
    both = np.vstack([reference, deformed])
    extent = max(float(np.ptp(both[:, 0])), 1e-12)
    hx = max(rel_width * extent, 3.0 * float(dist[k]), 1e-9)
    x0, x1 = cx - hx, cx + hx
    pts = np.vstack([reference, deformed, *others])
    inside = pts[(pts[:, 0] >= x0) & (pts[:, 0] <= x1)]
    if inside.shape[0] == 0:
        inside = np.vstack([c, near])
    y0, y1 = float(inside[:, 1].min()), float(inside[:, 1].max())
    pad = 0.15 * max(y1 - y0, 0.05 * hx)
    return x0, x1, y0 - pad, y1 + pad


def plot_interfaces(
    reference: np.ndarray,
    observed: np.ndarray | Sequence[np.ndarray] | None,
    samples: Sequence[np.ndarray] | None,
    paths: PathsLike,
    *,
    map_interface: np.ndarray | None = None,
    truth_interface: np.ndarray | None = None,
    zoom: bool = True,
    length_unit_factor: float = 1.0,
    sample_label: str = "posterior samples",
    max_samples: int = 200,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Undeformed, observed and sampled interfaces in the flow cell.

    Parameters
    ----------
    reference : array_like, shape (n, 2)
        Undeformed interface (ordered points).
    observed : array_like, shape (m, 2), or list of such arrays, or None
        Observed interface, or several snapshots (drawn black, increasingly
        opaque; the last one is the reference observation).
    samples : list of arrays, shape (k_i, 2) each, or None
        Interfaces computed for posterior samples (thin, semi-transparent).
    paths : path or sequence of paths
        Output files; format from the suffix.
    map_interface : array_like, shape (k, 2), optional
        Interface at the MAP estimate (green).
    truth_interface : array_like, shape (k, 2), optional
        Noise-free interface at the ground truth (purple, dotted).
    zoom : bool
        Add a second panel magnifying the region of largest deformation of the
        observed (else MAP, else first sample) interface.
    length_unit_factor : float
        Factor converting the input coordinates to mm (1 if already in mm,
        1e3 if in m).
    sample_label : str
        Legend entry of the samples.
    max_samples : int
        At most this many sample interfaces are drawn (evenly spaced subset).
    title : str, optional
        Figure title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    if not length_unit_factor > 0:
        raise ValueError(f"length_unit_factor: must be positive, got {length_unit_factor}")
    f = float(length_unit_factor)
    ref = as_points(reference, "reference", allow_empty=False) * f
    obs = [c * f for c in _as_curve_list(observed, "observed")]
    smp = [c * f for c in _as_curve_list(samples, "samples")]
    mp = None if map_interface is None else as_points(map_interface, "map_interface",
                                                      allow_empty=False) * f
    tru = None if truth_interface is None else as_points(truth_interface, "truth_interface",
                                                         allow_empty=False) * f
    out_paths = as_paths(paths)
    if max_samples < 1:
        raise ValueError(f"max_samples: must be >= 1, got {max_samples}")
    if len(smp) > max_samples:
        smp = [smp[i] for i in np.linspace(0, len(smp) - 1, max_samples).round().astype(int)]
    target = obs[-1] if obs else (mp if mp is not None else (smp[0] if smp else None))
    do_zoom = zoom and target is not None

    def draw(ax) -> list:
        handles = []
        if smp:
            lc = LineCollection(smp, colors=COLORS["samples"], linewidths=0.5,
                                alpha=max(0.08, min(0.5, 8.0 / len(smp))), zorder=2)
            ax.add_collection(lc)
            handles.append(Line2D([], [], color=COLORS["samples"], lw=0.8, alpha=0.6,
                                  label=f"{sample_label} ({len(smp)})"))
        (h,) = ax.plot(ref[:, 0], ref[:, 1], color=COLORS["reference"], ls="--", lw=1.2,
                       label="undeformed", zorder=3)
        handles.insert(0, h)
        obs_label = "observed" if len(obs) == 1 else f"observed ({len(obs)} snapshots)"
        for k, c in enumerate(obs):
            alpha = 1.0 if k == len(obs) - 1 else 0.3 + 0.5 * k / max(len(obs) - 1, 1)
            (h,) = ax.plot(c[:, 0], c[:, 1], color=COLORS["observed"], lw=1.4, alpha=alpha,
                           zorder=4,
                           label=obs_label)
            if k == len(obs) - 1:
                handles.append(h)
        if tru is not None:
            (h,) = ax.plot(tru[:, 0], tru[:, 1], color=COLORS["truth"], ls=":", lw=1.4,
                           label="ground truth", zorder=5)
            handles.append(h)
        if mp is not None:
            (h,) = ax.plot(mp[:, 0], mp[:, 1], color=COLORS["map"], lw=1.3, label="MAP",
                           zorder=5)
            handles.append(h)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        return handles

    allpts = np.vstack([ref] + obs + smp + ([mp] if mp is not None else [])
                       + ([tru] if tru is not None else []))
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.05 * np.ptp(allpts, axis=0).max()
    with paper_style():
        span = (hi - lo) + 2 * pad
        width = 6.0
        h_main = float(np.clip(width * span[1] / max(span[0], 1e-12), 0.8, 5.0))
        if do_zoom:
            x0, x1, y0, y1 = largest_deformation_box(
                ref, target, [c for c in obs + smp + [mp, tru] if c is not None])
            h_zoom = float(np.clip(width * (y1 - y0) / (x1 - x0), 0.8, 4.0))
        else:
            h_zoom = 0.0
        fig = Figure(figsize=(width, h_main + h_zoom + 1.2), layout="compressed")
        if do_zoom:
            ax, axz = fig.subplots(2, 1, height_ratios=(h_main, h_zoom))
        else:
            ax, axz = fig.add_subplot(), None
        handles = draw(ax)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        if axz is not None:
            draw(axz)
            axz.set_xlim(x0, x1)
            axz.set_ylim(y0, y1)
            axz.set_title("zoom: region of largest deformation", fontsize=8)
            ax.indicate_inset((x0, y0, x1 - x0, y1 - y0), inset_ax=None,
                              edgecolor="0.3", linewidth=0.8)
        fig.legend(handles=handles, loc="outside lower center",
                   ncols=min(len(handles), 3), frameon=False)
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)


def plot_interface_residual(
    points: np.ndarray,
    values: np.ndarray,
    paths: PathsLike,
    *,
    label: str = "standardized residual",
    unit: str = "-",
    reference: np.ndarray | None = None,
    length_unit_factor: float = 1.0,
    vmax: float | None = None,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Interface coloured by a signed scalar, diverging colormap centred at 0.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Ordered interface points.
    values : array_like, shape (n,)
        Scalar per point (e.g. standardized residual); segments take the mean
        of their end values.
    paths : path or sequence of paths
        Output files; format from the suffix.
    label : str
        Colour-bar label (without unit).
    unit : str
        Unit of ``values``.
    reference : array_like, shape (m, 2), optional
        Undeformed interface drawn grey dashed for orientation.
    length_unit_factor : float
        Factor converting coordinates to mm.
    vmax : float, optional
        Symmetric colour limit; default max |values|.
    title : str, optional
        Axes title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    if not length_unit_factor > 0:
        raise ValueError(f"length_unit_factor: must be positive, got {length_unit_factor}")
    p = as_points(points, "points", allow_empty=False) * float(length_unit_factor)
    if p.shape[0] < 2:
        raise ValueError("points: need at least 2 points")
    v = as_array(values, "values", shape=(p.shape[0],))
    ref = None if reference is None else (as_points(reference, "reference")
                                          * float(length_unit_factor))
    out_paths = as_paths(paths)
    lim = float(np.max(np.abs(v))) if vmax is None else float(vmax)
    if not lim > 0:
        lim = 1.0
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)

    segs = np.stack([p[:-1], p[1:]], axis=1)
    with paper_style():
        allpts = p if ref is None else np.vstack([p, ref])
        span = np.ptp(allpts, axis=0) + 1e-12
        width = 6.0
        height = float(np.clip(width * span[1] / span[0], 0.8, 5.0)) + 0.9
        fig = Figure(figsize=(width, height), layout="compressed")
        ax = fig.add_subplot()
        if ref is not None and ref.shape[0]:
            ax.plot(ref[:, 0], ref[:, 1], color=COLORS["reference"], ls="--", lw=1.0,
                    label="undeformed")
        lc = LineCollection(segs, array=0.5 * (v[:-1] + v[1:]), cmap=DIVERGING_CMAP, norm=norm,
                            linewidths=3.0, capstyle="round")
        ax.add_collection(lc)
        ax.scatter(p[:, 0], p[:, 1], c=v, cmap=DIVERGING_CMAP, norm=norm, s=9,
                   edgecolors="k", linewidths=0.25, zorder=3)
        cb = fig.colorbar(lc, ax=ax, pad=0.02, extend="neither" if vmax is None else "both",
                          location="bottom", shrink=0.6, aspect=35)
        cb.set_label(f"{label} [{unit}]")
        pad = 0.05 * span.max()
        ax.set_xlim(allpts[:, 0].min() - pad, allpts[:, 0].max() + pad)
        ax.set_ylim(allpts[:, 1].min() - pad, allpts[:, 1].max() + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        if ref is not None and ref.shape[0]:
            ax.legend(loc="upper right")
        if title:
            ax.set_title(title)
        return finish(fig, out_paths, dpi, return_figure)

"""Fluid-biofilm interface curves and scalar fields along the interface.

* :func:`plot_interfaces` -- undeformed interface (grey dashed), observed
  interface(s) (black), interfaces of posterior samples (thin, transparent),
  optional MAP interface, equal aspect in mm (paper Fig. "contoursamples"),
  over a second panel with the deflection profile: the signed distance of every
  curve from the undeformed interface (closest point projection, eq. cppdist)
  against the arc length of its foot point. At the scale of the flow cell a
  deformation of a few tens of micrometres and the spread of the posterior
  samples are invisible; the profile magnifies exactly that, so the samples'
  band, the observation's noise and a systematic misfit can be read off.
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

from ._validation import PathsLike, as_array, as_paths, as_points, finish
from .style import COLORS, DIVERGING_CMAP, paper_style

__all__ = ["deflection_profile", "plot_interface_residual", "plot_interfaces"]


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


def deflection_profile(reference: np.ndarray, curve: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of ``curve`` from ``reference`` along the reference's arc length.

    Parameters
    ----------
    reference : numpy.ndarray, shape (n, 2)
        Undeformed interface, an ordered polyline.
    curve : numpy.ndarray, shape (m, 2)
        Deformed (or observed) interface points, same length unit.

    Returns
    -------
    s : numpy.ndarray, shape (m,)
        Arc length of each point's closest point on ``reference``, sorted ascending.
    d : numpy.ndarray, shape (m,)
        Signed distance of each point from ``reference``, positive on the side its
        normal points to (left of the direction of travel: into the fluid for an
        interface ordered upstream to downstream), in the order of ``s``.
    """
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.projection import closest_points

    ref = Interface.polyline(reference)
    signed, foot, cell = closest_points(np.asarray(curve, float), ref)
    arc = ref.arc_length()
    start = ref.points[ref.cells[cell, 0]]
    s = arc[ref.cells[cell, 0]] + np.linalg.norm(foot - start, axis=1)
    order = np.argsort(s, kind="stable")
    return s[order], signed[order]


def plot_interfaces(
    reference: np.ndarray,
    observed: np.ndarray | Sequence[np.ndarray] | None,
    samples: Sequence[np.ndarray] | None,
    paths: PathsLike,
    *,
    map_interface: np.ndarray | None = None,
    truth_interface: np.ndarray | None = None,
    profile: bool = True,
    length_unit_factor: float = 1.0,
    sample_label: str = "posterior samples",
    max_samples: int = 200,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
    surface: tuple[np.ndarray, np.ndarray, np.ndarray, str] | None = None,
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
    profile : bool
        Add the deflection-profile panel (signed distance from the undeformed
        interface against arc length, in micrometres when below 0.1 mm, see the
        module docstring).
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
    surface : (points, triangles, values, label), optional
        A 3D surface rendered beside the section (points ``(n, 3)`` mm, x along the
        flow, y up, z across; triangles ``(m, 3)``), each triangle coloured by the mean
        of ``values`` ``(n,)`` at its corners (a diverging scale symmetric about 0,
        labelled ``label``).

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
    do_profile = profile and bool(obs or smp or mp is not None or tru is not None)

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

    def draw_profile(ax) -> None:
        prof = {"samples": [deflection_profile(ref, c) for c in smp],
                "observed": [deflection_profile(ref, c) for c in obs],
                "truth": [] if tru is None else [deflection_profile(ref, tru)],
                "map": [] if mp is None else [deflection_profile(ref, mp)]}
        dmax = max((np.abs(d).max() for v in prof.values() for _, d in v), default=0.0)
        unit, k = ("µm", 1e3) if dmax < 0.1 else ("mm", 1.0)
        if prof["samples"]:
            ax.add_collection(LineCollection(
                [np.column_stack([s_, k * d]) for s_, d in prof["samples"]],
                colors=COLORS["samples"], linewidths=0.6,
                alpha=max(0.1, min(0.6, 10.0 / len(smp))), zorder=2))
        for j, (s_, d) in enumerate(prof["observed"]):
            last = j == len(prof["observed"]) - 1
            ax.plot(s_, k * d, ls="none", marker="o", ms=1.6, color=COLORS["observed"],
                    alpha=1.0 if last else 0.3, zorder=4)
        for (s_, d) in prof["truth"]:
            ax.plot(s_, k * d, color=COLORS["truth"], ls=":", lw=1.4, zorder=5)
        for (s_, d) in prof["map"]:
            ax.plot(s_, k * d, color=COLORS["map"], lw=1.3, zorder=5)
        ax.axhline(0.0, color=COLORS["reference"], ls="--", lw=1.0, zorder=1)
        ax.set_xlim(0.0, float(np.sum(np.linalg.norm(np.diff(ref, axis=0), axis=1))))
        ax.autoscale(axis="y")
        ax.set_xlabel("arc length along the undeformed interface [mm]")
        ax.set_ylabel(f"deflection [{unit}]")
        ax.set_title("deflection normal to the undeformed interface "
                     "(+ to the left of its direction)", fontsize=8, loc="left")

    allpts = np.vstack([ref] + obs + smp + ([mp] if mp is not None else [])
                       + ([tru] if tru is not None else []))
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.05 * np.ptp(allpts, axis=0).max()
    with paper_style():
        span = (hi - lo) + 2 * pad
        width = 6.0
        h_main = float(np.clip(width * span[1] / max(span[0], 1e-12), 0.8, 5.0))
        h_prof = 2.2 if do_profile else 0.0
        fig = Figure(figsize=(width + (5.5 if surface is not None else 0.0),
                              h_main + h_prof + 1.0), layout="constrained")
        left = fig
        if surface is not None:
            left, right = fig.subfigures(1, 2, width_ratios=(width, 5.5))
            _draw_surface(right, *surface)
        if do_profile:
            ax, axp = left.subplots(2, 1, height_ratios=(h_main, h_prof))
        else:
            ax, axp = left.add_subplot(), None
        handles = draw(ax)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        if axp is not None:
            draw_profile(axp)
        fig.legend(handles=handles, loc="outside lower center",
                   ncols=min(len(handles), 3), frameon=False)
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)


def _draw_surface(fig, points: np.ndarray, triangles: np.ndarray, values: np.ndarray,
                  label: str) -> None:
    """A 3D surface on its own axes, triangles coloured by ``values`` (symmetric scale)."""
    from matplotlib import cm, colormaps, colors
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    pts = np.asarray(points, dtype=float)[:, [0, 2, 1]]  # plotted as (x, z, y): y up
    tri = np.asarray(triangles, dtype=np.int64)
    face = np.asarray(values, dtype=float)[tri].mean(axis=1)
    vmax = float(np.nanmax(np.abs(face))) or 1.0
    norm = colors.Normalize(-vmax, vmax)
    cmap = colormaps["RdBu_r"]
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(pts[tri], facecolors=cmap(norm(face)),
                                         edgecolors="none"))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(0.0, hi[2])
    ax.set_box_aspect(np.maximum(hi - np.array([lo[0], lo[1], 0.0]), 1e-9))
    ax.view_init(elev=28, azim=-60)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]")
    ax.set_zlabel("y [mm]")
    sm = cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, shrink=0.6, label=label, location="bottom")


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
    surface : (points, triangles, values, label), optional
        A 3D surface rendered beside the section (points ``(n, 3)`` mm, x along the
        flow, y up, z across; triangles ``(m, 3)``), each triangle coloured by the mean
        of ``values`` ``(n,)`` at its corners (a diverging scale symmetric about 0,
        labelled ``label``).

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

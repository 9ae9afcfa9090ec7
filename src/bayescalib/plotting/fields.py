"""Field solutions of the FSI forward model on the (deformed) flow-cell mesh
(paper Fig. "FSIresult").

Three stacked panels: fluid velocity magnitude with streamlines, fluid
pressure, and solid displacement magnitude; equal aspect, lengths in mm, the
fluid-biofilm interface drawn on top of every panel. A 3D model's fields are drawn
in a plane section (:func:`bayescalib.stages.figures.section_fields`): the same 2D
arrays, with 3-component velocity and displacement.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.tri import LinearTriInterpolator, Triangulation

from ._validation import PathsLike, as_array, as_paths, as_points, finish
from .style import COLORS, paper_style

__all__ = ["plot_failed_solve", "plot_fields"]


def _validate_triangles(triangles, n_points: int) -> np.ndarray:
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] < 1:
        raise ValueError(f"triangles: expected shape (t, 3) with t >= 1, got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        if not np.all(np.isfinite(t)) or np.any(t != np.round(t)):
            raise ValueError("triangles: entries must be integer point indices")
        t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= n_points:
        raise ValueError(f"triangles: indices must lie in [0, {n_points - 1}], "
                         f"got [{t.min()}, {t.max()}]")
    return t


def _ncomp(a) -> int:
    """The number of components of a vector field given as (p, 2) or (p, 3) (2 for
    anything else, so that the shape check says what is expected)."""
    shape = np.shape(a)
    return 3 if len(shape) == 2 and shape[1] == 3 else 2


def _shape_quality(xy: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """4 sqrt(3) area / (sum of squared edges): 1 for an equilateral triangle, 0 for a
    degenerate one."""
    p = xy[tri]
    e = p[:, [1, 2, 0]] - p
    area = 0.5 * np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    return 4.0 * np.sqrt(3.0) * area / np.maximum((e ** 2).sum(axis=(1, 2)), 1e-300)


def _magnitude(v: np.ndarray) -> np.ndarray:
    return np.hypot(v[:, 0], v[:, 1]) if v.shape[1] == 2 else np.linalg.norm(v, axis=1)


def plot_fields(
    points: np.ndarray,
    triangles: np.ndarray,
    velocity: np.ndarray,
    pressure: np.ndarray,
    displacement: np.ndarray,
    paths: PathsLike,
    *,
    interface: np.ndarray | None = None,
    solid_mask_triangles: np.ndarray | None = None,
    deform: bool = False,
    length_unit_factor: float = 1.0,
    velocity_unit_factor: float = 1.0,
    pressure_unit_factor: float = 1.0,
    streamlines: bool = True,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Velocity magnitude, pressure and displacement magnitude on the mesh.

    Parameters
    ----------
    points : array_like, shape (p, 2)
        Mesh vertices (reference or already deformed configuration).
    triangles : array_like of int, shape (t, 3)
        Vertex indices of the triangles.
    velocity : array_like, shape (p, 2) or (p, 3)
        Fluid velocity at the vertices (values in solid triangles are ignored). Three
        components: a section of a 3D field (e.g. the mid-plane of a 3D model); the
        magnitude is the full vector's, the streamlines those of its in-plane part
        (x, y).
    pressure : array_like, shape (p,)
        Fluid pressure at the vertices.
    displacement : array_like, shape (p, 2) or (p, 3)
        Displacement at the vertices (same length unit as ``points``); three
        components as for ``velocity`` (magnitude of the full vector, ``deform`` by the
        in-plane part).
    paths : path or sequence of paths
        Output files; format from the suffix.
    interface : array_like, shape (n, 2), optional
        Fluid-biofilm interface (in the units of ``points``; plotted as given,
        so pass the deformed interface when ``deform`` is used).
    solid_mask_triangles : array_like of bool, shape (t,), optional
        True for biofilm (solid) triangles. The velocity and pressure panels
        show fluid triangles only, the displacement panel solid ones only;
        None treats every triangle as both.
    deform : bool
        Plot on ``points + displacement`` (for a reference-configuration mesh).
    length_unit_factor : float
        Converts lengths (points, displacement, interface) to mm.
    velocity_unit_factor : float
        Converts velocities to mm/s.
    pressure_unit_factor : float
        Converts pressures to Pa (e.g. 1e-3 for a pressure in mPa).
    streamlines : bool
        Overlay streamlines of the fluid velocity.
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
    for val, nm in ((length_unit_factor, "length_unit_factor"),
                    (velocity_unit_factor, "velocity_unit_factor"),
                    (pressure_unit_factor, "pressure_unit_factor")):
        if not val > 0:
            raise ValueError(f"{nm}: must be positive, got {val}")
    pts = as_points(points, "points", allow_empty=False)
    n = pts.shape[0]
    tri = _validate_triangles(triangles, n)
    vel = as_array(velocity, "velocity", shape=(n, _ncomp(velocity))) * velocity_unit_factor
    pres = as_array(pressure, "pressure", shape=(n,)) * pressure_unit_factor
    disp = as_array(displacement, "displacement",
                    shape=(n, _ncomp(displacement))) * length_unit_factor
    pts = pts * length_unit_factor
    itf = None if interface is None else as_points(interface, "interface") * length_unit_factor
    if solid_mask_triangles is None:
        solid = np.zeros(tri.shape[0], dtype=bool)
        has_solid = False
    else:
        solid = np.asarray(solid_mask_triangles)
        if solid.shape != (tri.shape[0],):
            raise ValueError(f"solid_mask_triangles: expected shape ({tri.shape[0]},), "
                             f"got {solid.shape}")
        solid = solid.astype(bool)
        has_solid = True
    out_paths = as_paths(paths)
    xy = pts + disp[:, :2] if deform else pts
    # the worst-shaped triangles first: Agg dilates each gouraud triangle by half a
    # pixel with mitred corners, which stretches a needle's acute corner (and its
    # colour) far over its neighbours; drawn first, the neighbours paint it over. A
    # plane section of a tetrahedral mesh (a 3D model's) has such needles
    order = np.argsort(_shape_quality(xy, tri), kind="stable")
    tri, solid = tri[order], solid[order]

    fluid_tri = Triangulation(xy[:, 0], xy[:, 1], tri, mask=solid if has_solid else None)
    solid_tri = Triangulation(xy[:, 0], xy[:, 1], tri, mask=~solid if has_solid else None)
    speed = _magnitude(vel)
    dmag = _magnitude(disp)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = hi - lo
    width = 6.0
    h_panel = float(np.clip(width * span[1] / max(span[0], 1e-12), 1.0, 4.0))

    with paper_style():
        fig = Figure(figsize=(width + 1.0, 3 * h_panel + 1.0), layout="compressed")
        axes = fig.subplots(3, 1, sharex=True, sharey=True)
        specs = [
            (fluid_tri, speed, "viridis", "velocity magnitude |v| [mm/s]", "fluid velocity"),
            (fluid_tri, pres, "cividis", "pressure p [Pa]", "fluid pressure"),
            (solid_tri, dmag, "magma", "displacement magnitude |u| [mm]",
             "solid displacement" if has_solid else "displacement"),
        ]
        for k, (ax, (tr, val, cmap, clabel, name)) in enumerate(zip(axes, specs)):
            # outline of the whole mesh in light grey, so masked parts stay visible
            ax.tripcolor(Triangulation(xy[:, 0], xy[:, 1], tri), np.ones(tri.shape[0]),
                         cmap="Greys", vmin=0, vmax=6, shading="flat", rasterized=True)
            shown = tri if tr.mask is None else tri[~tr.mask]
            vis = val[np.unique(shown)] if shown.size else val
            pc = ax.tripcolor(tr, val, cmap=cmap, shading="gouraud", rasterized=True,
                              vmin=float(vis.min()), vmax=float(vis.max()))
            cb = fig.colorbar(pc, ax=ax, pad=0.02, shrink=0.95)
            cb.set_label(clabel, fontsize=7.5)
            if k == 0 and streamlines:
                _streamlines(ax, fluid_tri, vel[:, :2], lo, hi)
            if itf is not None and itf.shape[0] >= 2:
                ax.plot(itf[:, 0], itf[:, 1], color="w", lw=2.2, zorder=4)
                ax.plot(itf[:, 0], itf[:, 1], color=COLORS["observed"], lw=1.0, zorder=5,
                        label="interface")
            ax.set_aspect("equal")
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_ylabel("y [mm]")
            ax.set_title(name, fontsize=8, loc="left")
        axes[-1].set_xlabel("x [mm]")
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)


def plot_failed_solve(paths: PathsLike, title: str, reason: str, *, dpi: float = 200,
                      return_figure: bool = False):
    """The place of a field figure whose solve failed: its title and the reason.

    Parameters
    ----------
    paths : path or sequence of paths
        Output files; format from the suffix.
    title : str
        What the fields would have shown (e.g. the solve's parameter values).
    reason : str
        Why there are no fields, in plain words (wrapped to the figure's width).
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    import textwrap

    out_paths = as_paths(paths)
    with paper_style():
        fig = Figure(figsize=(6.0, 2.0))
        ax = fig.add_subplot(1, 1, 1)
        ax.set_axis_off()
        ax.text(0.5, 0.5, textwrap.fill(str(reason), 80), ha="center", va="center",
                fontsize=8, transform=ax.transAxes)
        fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)


def _streamlines(ax, tri: Triangulation, vel: np.ndarray, lo: Sequence[float],
                 hi: Sequence[float], n: int = 200, n_seeds: int = 12) -> None:
    """Whole streamlines of the piecewise-linear velocity, interpolated to a grid.

    Lines start at ``n_seeds`` heights spread over the inflow (the first grid column
    with fluid, in equal steps of the flow rate through it, so that the spacing of the
    lines shows the speed) and, where the flow turns back (a recirculation behind the
    biofilm), on a vertical line through the backflow region; each line is followed in
    both directions to its end (no broken segments).
    """
    gx = np.linspace(lo[0], hi[0], n)
    gy = np.linspace(lo[1], hi[1], max(8, int(n * (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-12))))
    X, Y = np.meshgrid(gx, gy)
    u = LinearTriInterpolator(tri, vel[:, 0])(X, Y)
    v = LinearTriInterpolator(tri, vel[:, 1])(X, Y)
    if np.ma.count(u) < 4 or not np.ma.max(np.hypot(u, v)) > 0:
        return
    fluid = ~np.ma.getmaskarray(u)
    cols = np.flatnonzero(fluid.any(axis=0))
    col = cols[min(1, cols.size - 1)]
    flux = np.where(fluid[:, col], np.abs(u.filled(0.0)[:, col]), 0.0)
    seeds = []
    if flux.sum() > 0:
        cum = np.cumsum(flux) / flux.sum()
        levels = (np.arange(n_seeds) + 0.5) / n_seeds
        seeds += [(gx[col], float(np.interp(q, cum, gy))) for q in levels]
    back = fluid & (u.filled(0.0) < 0)
    if back.sum() >= 4:
        xb = float(np.median(X[back]))
        yb = Y[back]
        seeds += [(xb, float(y)) for y in np.linspace(yb.min(), yb.max(), 6)[1:-1]]
    if not seeds:
        return
    try:
        ax.streamplot(gx, gy, u, v, color="0.1", linewidth=0.5, start_points=np.array(seeds),
                      arrowsize=0.6, zorder=3, broken_streamlines=False,
                      integration_direction="both")
    except ValueError as exc:  # irregular grids or fully masked rows
        warnings.warn(f"streamlines skipped: {exc}", stacklevel=3)

"""Synthetic OCT volumes of a 3D colony: the recording a user of the 3D model brings.

The 3D analogue of :mod:`bayescalib.geometry.recording`: a stack of B-scans (planes
``z = const``, rows from the top) of one colony at a few flow rates, made from the 3D
model's deformed surfaces so that the truth is known; written as the files an OCT
system exports (a multi-page 16-bit TIFF per flow rate, with a ``recording.json`` that
says how to read them) by :func:`bayescalib.io.volumes.write_volume_recording`.

Rendering (:func:`render_volume`)
---------------------------------
A colony imaged from above is a height field: its surface is ``y = h(x, z)`` over its
footprint (:func:`height_field`: the highest crossing of the vertical line through
``(x, z)`` with the surface's triangles; a surface that a vertical line crosses more
than once, an overhang, is rendered by its top, as an OCT beam from above would see it
first). Each voxel's biofilm occupancy is the share of its height below ``h``, exact
along ``y`` and averaged over ``supersample^2`` sub-columns in ``x`` and ``z``; the
substrate is the band ``-substrate_thickness <= y < 0``. Then, as for the B-scans of
:func:`bayescalib.geometry.recording.render_recording_scan`,

    ``I = (G * a_biofilm + c_s G * a_substrate) S + noise N``

with ``G`` a Gaussian point-spread function of ``psf_sigma`` voxels along every axis,
``S`` gamma speckle of ``looks`` looks and ``N`` standard normal noise: fluid 0,
biofilm 1, substrate ``c_s`` in mean.

The volume's grid (:func:`volume_grid`) has its voxel edges on multiples of the voxel
size along ``y``, so the floor ``y = 0`` is a layer edge, with the margin of fluid
around the colony on its sides and above it.

Every random number comes from one :class:`numpy.random.Generator` seeded by the
caller, used volume after volume in order: the same inputs give the same files.
"""

from __future__ import annotations

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.recording import ScanSettings

__all__ = ["height_field", "render_volume", "volume_grid"]


def height_field(surface: Interface, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The top of a surface above each ``(x, z)``: the highest crossing of the vertical
    line with its triangles.

    Parameters
    ----------
    surface : Interface
        Triangulated surface, mm (``dim == 3``).
    x, z : ndarray, shape (nx,), (nz,)
        Grid coordinates, mm.

    Returns
    -------
    ndarray, shape (nz, nx)
        ``h(x, z)`` in mm; NaN where no triangle lies above the point.
    """
    if surface.dim != 3:
        raise ValueError("height_field needs a 3D surface")
    x = np.asarray(x, dtype=float)
    z = np.asarray(z, dtype=float)
    h = np.full((z.size, x.size), np.nan)
    tri = surface.points[surface.cells]  # (m, 3, 3)
    for p in tri:
        (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = p
        i0, i1 = np.searchsorted(x, [min(x0, x1, x2), max(x0, x1, x2)], side="left")
        k0, k1 = np.searchsorted(z, [min(z0, z1, z2), max(z0, z1, z2)], side="left")
        i1 = min(i1 + 1, x.size)
        k1 = min(k1 + 1, z.size)
        if i0 >= i1 or k0 >= k1:
            continue
        det = (z1 - z2) * (x0 - x2) + (x2 - x1) * (z0 - z2)
        if abs(det) < 1e-18:  # a vertical triangle: seen edge-on from above
            continue
        X, Z = np.meshgrid(x[i0:i1], z[k0:k1])
        a = ((z1 - z2) * (X - x2) + (x2 - x1) * (Z - z2)) / det
        b = ((z2 - z0) * (X - x2) + (x0 - x2) * (Z - z2)) / det
        c = 1.0 - a - b
        inside = (a >= -1e-12) & (b >= -1e-12) & (c >= -1e-12)
        if not inside.any():
            continue
        y = a * y0 + b * y1 + c * y2
        block = h[k0:k1, i0:i1]
        block[inside] = np.fmax(block[inside], y[inside])
    return h


def volume_grid(bounds: np.ndarray, settings: ScanSettings, slice_spacing: float
                ) -> tuple[tuple[int, int, int], tuple[float, float, float]]:
    """A volume's grid covering ``bounds`` with the margin, the floor on a layer edge.

    Parameters
    ----------
    bounds : array_like, shape (2, 3)
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` of everything to be seen, mm.
    settings : ScanSettings
        ``pixel_size`` is the B-scans' pixel (x and y), ``margin`` the fluid around the
        colony, ``rows_below_floor`` the substrate and below.
    slice_spacing : float
        Distance between B-scans (z), mm.

    Returns
    -------
    shape : (int, int, int)
        ``(nz, ny, nx)``.
    origin : (float, float, float)
        Centre of voxel ``[0, ny - 1, 0]``, mm.
    """
    b = np.asarray(bounds, dtype=float)
    s, dz, m = settings.pixel_size, float(slice_spacing), settings.margin
    c0, c1 = int(np.floor((b[0, 0] - m) / s)), int(np.ceil((b[1, 0] + m) / s))
    k0, k1 = int(np.floor((b[0, 2] - m) / dz)), int(np.ceil((b[1, 2] + m) / dz))
    top = int(np.ceil((b[1, 1] + m) / s))
    below = settings.rows_below_floor
    return ((k1 - k0, top + below, c1 - c0),
            ((c0 + 0.5) * s, (-below + 0.5) * s, (k0 + 0.5) * dz))


def render_volume(surface: Interface, *, shape: tuple[int, int, int],
                  origin: tuple[float, float, float], slice_spacing: float,
                  settings: ScanSettings, rng: np.random.Generator) -> np.ndarray:
    """OCT-like volume of a colony on the flow-cell floor (module docstring).

    Parameters
    ----------
    surface : Interface
        The colony's surface (rim on ``y = 0``), mm.
    shape, origin
        From :func:`volume_grid`.
    slice_spacing : float
        Distance between B-scans, mm.
    settings : ScanSettings
    rng : numpy.random.Generator
        Source of the speckle and the noise.

    Returns
    -------
    ndarray of float, shape (nz, ny, nx)
        Intensity; B-scan row 0 is the top.
    """
    from scipy.ndimage import gaussian_filter

    nz, ny, nx = shape
    s, dz, q = settings.pixel_size, float(slice_spacing), int(settings.supersample)
    sub = (np.arange(q) + 0.5) / q - 0.5  # sub-column offsets, in voxels
    x = (origin[0] + np.arange(nx)[:, None] * s + sub[None, :] * s).ravel()
    z = (origin[2] + np.arange(nz)[:, None] * dz + sub[None, :] * dz).ravel()
    h = np.nan_to_num(height_field(surface, x, z), nan=0.0)  # (nz q, nx q)
    y_lo = origin[1] + (ny - 1 - np.arange(ny)) * s - 0.5 * s  # each row's bottom edge
    occ = np.zeros(shape)
    for r in range(ny):
        frac = np.clip((h - max(y_lo[r], 0.0)) / s, 0.0, 1.0) * (y_lo[r] + s > 0)
        occ[:, r, :] = frac.reshape(nz, q, nx, q).mean(axis=(1, 3))
    t = settings.substrate_thickness
    band = np.clip((np.minimum(y_lo + s, 0.0) - np.maximum(y_lo, -t)) / s, 0.0, 1.0)
    img = occ + settings.substrate_intensity * band[None, :, None] * np.ones(shape)
    sig = float(settings.psf_sigma)
    if sig > 0:
        img = gaussian_filter(img, sigma=(sig * s / dz, sig, sig), mode="nearest")
    if settings.looks is not None:
        img = img * rng.gamma(float(settings.looks), 1.0 / float(settings.looks), size=shape)
    if settings.noise > 0:
        img = img + float(settings.noise) * rng.standard_normal(shape)
    return img

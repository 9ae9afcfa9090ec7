"""3D observations (issue 40 item 2): a colony's surface from an OCT volume
(:mod:`bayescalib.geometry.volume`), from surface files (:mod:`bayescalib.io.surfaces`),
its plane sections (:func:`bayescalib.geometry.surface.plane_section`) and the closest
point projection onto triangles (:func:`bayescalib.geometry.projection.closest_points`),
against analytic half-ellipsoids, planes and spheres."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from _interface_shapes import icosphere, square

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.geometry.surface import (
    SurfaceError,
    colony_surface,
    enclosed_volume,
    plane_section,
    taubin_smooth,
)
from bayescalib.geometry.volume import volume_surface
from bayescalib.io.observations import ObservationError
from bayescalib.io.surfaces import header_units, read_surface

# the colony: half-ellipsoid on the floor y = 0, semi-axes a (x), b (y), c (z), mm
A, B, C = 0.4, 0.15, 0.3
XC, ZC = 0.5, 0.4
S = 0.01  # voxel size, mm
NZ, NY, NX = 80, 25, 100


def ellipsoid_distance(p, a=A, b=B, c=C, xc=XC, zc=ZC):
    """First-order distance of points (k, 3) to the ellipsoid, ``(F - 1) / |grad F|`` with
    ``F = sum (x_i / a_i)^2``; its error is O(d^2 / R), < 1e-4 mm at d = 1 voxel here."""
    q = (p - [xc, 0.0, zc]) / [a, b, c]
    f = np.sum(q**2, axis=1)
    g = 2 * np.linalg.norm(q / [a, b, c], axis=1)
    return (f - 1) / g


def half_ellipsoid_mask(s=S, shape=(NZ, NY, NX), origin=(0.0, None, 0.0)):
    """Mask of the half-ellipsoid; the floor y = 0 is the bottom face of the volume.
    ``s``: voxel size, or ``(dx, dy, dz)``, mm."""
    dx, dy, dz = np.broadcast_to(np.asarray(s, dtype=float), (3,))
    nz, ny, nx = shape
    y0 = 0.5 * dy if origin[1] is None else origin[1]
    k, r, col = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    x, y, z = origin[0] + col * dx, y0 + (ny - 1 - r) * dy, origin[2] + k * dz
    return ((x - XC) / A) ** 2 + (y / B) ** 2 + ((z - ZC) / C) ** 2 <= 1, (origin[0], y0, origin[2])


def half_ellipsoid_mesh(nt=40, nph=120, a=A, b=B, c=C, xc=XC, zc=ZC):
    """Parametric half-ellipsoid (elevation rings and a pole), outward normals, rim on y=0."""
    th = np.linspace(0, math.pi / 2, nt + 1)[:-1]
    ph = np.linspace(0, 2 * math.pi, nph + 1)[:-1]
    T, P = np.meshgrid(th, ph, indexing="ij")
    pts = np.column_stack([xc + a * (np.cos(T) * np.cos(P)).ravel(), b * np.sin(T).ravel(),
                           zc + c * (np.cos(T) * np.sin(P)).ravel()])
    pts = np.vstack([pts, [xc, b, zc]])
    idx = np.arange(nt * nph).reshape(nt, nph)
    nxt = np.roll(idx, -1, axis=1)
    q0, q1, q2, q3 = idx[:-1], nxt[:-1], nxt[1:], idx[1:]
    tris = np.vstack([np.column_stack([q0.ravel(), q1.ravel(), q2.ravel()]),
                      np.column_stack([q0.ravel(), q2.ravel(), q3.ravel()]),
                      np.column_stack([idx[-1], nxt[-1], np.full(nph, nt * nph)])])
    if enclosed_volume(pts, tris, 0.0) < 0:
        tris = tris[:, ::-1]
    return Interface.surface(pts, tris, name="half-ellipsoid")


def true_area(a=A, b=B, c=C, n=800):
    """Lateral area of the half-ellipsoid from a fine parametric mesh (O(h^2): < 1e-5)."""
    return half_ellipsoid_mesh(n, 4 * n, a, b, c).total_measure


# ------------------------------------------------------------------ volume -> surface
@pytest.fixture(scope="module")
def mc_surfaces():
    mask, org = half_ellipsoid_mask()
    raw = volume_surface(mask, voxel_size=S, units="mm", origin=org, iterations=0)
    smooth = volume_surface(mask, voxel_size=S, units="mm", origin=org)
    return mask, org, raw, smooth


def test_volume_surface_of_a_half_ellipsoid_is_within_half_a_voxel(mc_surfaces):
    _, _, (raw, info0), (surf, info) = mc_surfaces
    v_true = 2 / 3 * math.pi * A * B * C
    a_true = true_area()
    for s_, inf in ((raw, info0), (surf, info)):
        d = ellipsoid_distance(s_.points)
        low = s_.points[:, 1] < S
        # every marching-cubes vertex of a binary mask is the midpoint of a voxel edge
        # between an inside and an outside centre: within s/2 of the true surface (the
        # smoothing keeps it so: measured 0.42 s raw / 0.42 s smoothed). In the lowest
        # layer the surface turns onto the floor at the centres of the fluid voxels next
        # to the colony's foot (a chamfer up to one voxel: measured 0.85 s / 0.72 s)
        assert np.abs(d[~low]).max() <= 0.5 * S
        assert np.abs(d[low]).max() <= 1.0 * S
        # volume: the voxel count of the mask (measured -0.15 % raw, -0.04 % smoothed)
        assert inf["volume_mm3"] == pytest.approx(v_true, rel=0.01)
        # the surface is one piece, open along its rim on the floor, normals outward
        assert inf["floor"]["y_mm"] == pytest.approx(0.0, abs=1e-12)
        assert s_.points[:, 1].min() == pytest.approx(0.0, abs=1e-5)
        out = np.einsum("md,md->m", s_.normals, s_.centres - [XC, 0.0, ZC])
        assert np.all(out > 0)
    # Taubin smoothing takes out the staircase: RMS distance 0.235 s -> 0.149 s; the
    # staircase of the raw surface adds 8.9 % area, the smoothed one 1.0 % (a flat
    # triangle over a voxel-sized bump still adds some); the volume moves by 0.11 %
    rms = [float(np.sqrt(np.mean(ellipsoid_distance(x.points) ** 2))) for x in (raw, surf)]
    assert rms[1] < rms[0] and rms[1] <= 0.2 * S
    assert info0["area_mm2"] > 1.05 * a_true
    assert info["area_mm2"] == pytest.approx(a_true, rel=0.03)
    assert abs(info["volume_change"]) < 0.005
    assert info["smoothing_iterations"] == 20 and info["colonies"] == 1


def test_volume_surface_from_b_scans_and_in_um(mc_surfaces):
    mask, org, _, (surf, _) = mc_surfaces
    # a list of B-scans, sizes in um: the same surface
    got, info = volume_surface([m for m in mask], voxel_size=(10.0, 10.0, 10.0), units="um",
                               origin=[1000 * v for v in org])
    np.testing.assert_allclose(got.points, surf.points, atol=1e-12)
    assert info["voxel_size_mm"] == pytest.approx([S, S, S])


def test_volume_surface_with_anisotropic_voxels():
    # OCT voxels differ per axis (axial y finer than lateral x, B-scan spacing z coarser):
    # (dx, dy, dz) = (10, 5, 20) um maps array axes (k, row, col) to (z, y, x)
    vox = (0.01, 0.005, 0.02)
    mask, org = half_ellipsoid_mask(vox, (40, 40, 100))
    surf, info = volume_surface(mask, voxel_size=[1000 * v for v in vox], units="um",
                                origin=[1000 * v for v in org])
    d = ellipsoid_distance(surf.points)
    # within half the largest voxel edge above the lowest layer, one edge in it
    assert np.abs(d[surf.points[:, 1] > vox[1]]).max() <= 0.5 * max(vox)
    assert np.abs(d).max() <= max(vox)
    assert info["volume_mm3"] == pytest.approx(2 / 3 * math.pi * A * B * C, rel=0.01)
    lo, hi = surf.bounds
    np.testing.assert_allclose(hi - lo, [2 * A, B, 2 * C], atol=max(vox))
    # positional uncertainty: the quantisation along the normals lies between the finest
    # and the coarsest edge times MASK_SURFACE_RMS (a mask: no image noise), and the
    # surface is as close to the truth as that says (measured RMS 0.0012 mm, bound 0.0018)
    from bayescalib.geometry.volume import MASK_SURFACE_RMS

    q = info["sigma_quantisation_mm"]
    assert MASK_SURFACE_RMS * min(vox) < q < MASK_SURFACE_RMS * max(vox)
    assert float(np.sqrt(np.mean(d[surf.points[:, 1] > vox[1]] ** 2))) < 1.5 * q
    assert info["sigma_noise_mm"] is None and info["sigma_mm"] == q


def test_volume_surface_of_a_noisy_scan_over_a_bright_substrate():
    # a greyscale volume: biofilm 1, fluid 0, a bright substrate (2) below the floor y = 0,
    # Gaussian blur and noise; segmented with the 2D rules (Otsu), the floor found as the
    # bright band (find_floor's rule a), within about a voxel of the truth
    from scipy.ndimage import gaussian_filter

    s, below = 0.02, 4
    mask, org = half_ellipsoid_mask(s, (40, 12 + below, 50), (0.0, 0.5 * s - below * s, 0.0))
    img = mask.astype(float)
    img[:, -below:, :] = 2.0
    rng = np.random.default_rng(1)
    img = gaussian_filter(img, 0.7) + 0.1 * rng.standard_normal(img.shape)
    surf, info = volume_surface(img, voxel_size=s, units="mm", origin=org,
                                segmentation={"threshold": 0.5})
    assert info["kind"] == "scan" and info["floor"]["method"] == "bright band"
    # the substrate's surface (the band's edge) is found within 1.5 voxels of y = 0 (here one
    # voxel low: the 2D rule puts the edge where the layer's median falls half-way from the
    # band's peak to the biofilm level, and a layer above the band is mostly fluid); the cut
    # lies on the top of the band's blurred halo, as in 2D (a few voxels: here 3)
    assert info["floor"]["edge_y_mm"] == pytest.approx(0.0, abs=1.5 * s)
    y_cut = info["floor"]["y_mm"]
    assert 0.0 <= y_cut <= 4 * s
    d = ellipsoid_distance(surf.points)
    assert np.abs(d).max() <= 1.0 * s
    # the volume above the cut: the half-ellipsoid's above y_cut, pi a c (b - y)^2 (2b + y) / (3 b^2)
    v_cut = math.pi * A * C * (B - y_cut) ** 2 * (2 * B + y_cut) / (3 * B**2)
    # measured -5.5 %: the half-way threshold of a blurred curved edge lies inside it by
    # about sigma^2 kappa / 2 (sigma = 1.2 voxels of point spread and pre-filter, the flanks'
    # radius of curvature b^2 / a = 2.8 voxels: ~0.25 voxel over a colony 7.5 voxels high)
    assert info["volume_mm3"] == pytest.approx(v_cut, rel=0.08)
    assert info["volume_mm3"] < v_cut
    # positional uncertainty of a scan: the image noise over the contour's gradient (the
    # middle B-scan's 2D estimate times the third axis's filter gain: noise 0.1 on a step
    # of 1 blurred over ~1 voxel) in quadrature with the quantisation (0.15 s)
    assert info["sigma_quantisation_mm"] == pytest.approx(0.15 * s, rel=1e-6)
    assert 0.01 * s < info["sigma_noise_mm"] < 0.5 * s
    # the surface is within a few of these of the truth (the blur's inward bias on the
    # curved flanks, ~0.25 voxel, adds to it; see the volume test above)
    rms = float(np.sqrt(np.mean(d ** 2)))
    assert rms < 3.0 * info["sigma_mm"]
    assert info["sigma_mm"] == pytest.approx(math.hypot(info["sigma_noise_mm"],
                                                        info["sigma_quantisation_mm"]))


def test_volume_surface_refuses_what_a_user_gets_wrong():
    mask, org = half_ellipsoid_mask(0.02, (40, 12, 50))
    ok = {"voxel_size": 0.02, "units": "mm", "origin": org}
    with pytest.raises(SurfaceError, match="no length unit.*units="):
        volume_surface(mask, **{**ok, "units": None})
    with pytest.raises(SurfaceError, match="unknown length unit 'inch'"):
        volume_surface(mask, **{**ok, "units": "inch"})
    with pytest.raises(SurfaceError, match="no voxel_size given"):
        volume_surface(mask, **{**ok, "voxel_size": None})
    with pytest.raises(SurfaceError, match=r"voxel_size must be > 0 mm.*-1"):
        volume_surface(mask, **{**ok, "voxel_size": (0.02, -1, 0.02)})
    with pytest.raises(SurfaceError, match="no origin given"):
        volume_surface(mask, **{**ok, "origin": None})
    with pytest.raises(SurfaceError, match=r"single value \(0\)"):
        volume_surface(np.zeros_like(mask), **ok)
    with pytest.raises(SurfaceError, match="shape"):
        volume_surface(mask[0], **ok)
    # two colonies: how many, their sizes, how to pick one
    two = mask.copy()
    two[30:34, 2:5, 2:6] = True  # a 4 x 3 x 4 speck
    with pytest.raises(SurfaceError, match=r"2 separate colonies.*#1: 48 voxels.*component=k"):
        volume_surface(two, **ok)
    picked, info = volume_surface(two, **ok, component=0)
    assert info["colonies"] == 2 and info["colony_voxels"] == int(mask.sum())
    assert picked.n_cells == volume_surface(mask, **ok)[0].n_cells
    # cut off by the field of view: the colony reaches the x max face
    with pytest.raises(SurfaceError, match=r"touches the volume's border on the x max \("):
        volume_surface(mask[:, :, :40], **ok)
    # nothing above the floor
    with pytest.raises(SurfaceError, match="no foreground .*above the floor"):
        volume_surface(mask, **ok, floor=0.3)
    with pytest.raises(SurfaceError, match="floor must be"):
        volume_surface(mask, **ok, floor="bottom")


# ------------------------------------------------------------------ plane sections
def test_plane_section_of_a_half_ellipsoid_is_the_half_ellipse():
    surf = half_ellipsoid_mesh()
    for dz in (0.0, 0.1, -0.2):
        sec = plane_section(surf, (0.0, 0.0, ZC + dz))
        k = math.sqrt(1 - (dz / C) ** 2)  # the section: semi-axes a k, b k
        p = sec.points
        assert sec.dim == 2 and sec.is_chain() and sec.n_cells == sec.n_points - 1
        # the nodes lie on the analytic half-ellipse up to the mesh's chordal sag
        # (h^2 / 8R with h ~ 2 pi a / 120 and R ~ b^2 / a: < 2e-4 mm)
        r = np.sqrt(((p[:, 0] - XC) / (A * k)) ** 2 + (p[:, 1] / (B * k)) ** 2)
        np.testing.assert_allclose(r, 1.0, atol=2e-3)
        # from the upstream foot to the downstream foot, on the floor, normals up
        assert p[0, 0] == pytest.approx(XC - A * k, abs=1e-3) and p[0, 1] == 0.0
        assert p[-1, 0] == pytest.approx(XC + A * k, abs=1e-3) and p[-1, 1] == 0.0
        assert np.all(sec.normals[:, 1][np.abs(sec.centres[:, 0] - XC) < 0.5 * A * k] > 0.5)
    # a general vertical plane through the axis at angle t: semi-axis 1/sqrt(c^2/a^2 + s^2/c^2)
    t = 0.6
    n = (-math.sin(t), 0.0, math.cos(t))
    sec = plane_section(surf, (XC, 0.0, ZC), n)
    e_u = np.array([math.cos(t), 0.0, math.sin(t)])
    u0 = float(np.dot([XC, 0.0, ZC], e_u))
    half = 1 / math.sqrt((math.cos(t) / A) ** 2 + (math.sin(t) / C) ** 2)
    r = np.sqrt(((sec.points[:, 0] - u0) / half) ** 2 + (sec.points[:, 1] / B) ** 2)
    np.testing.assert_allclose(r, 1.0, atol=2e-3)
    assert sec.points[0, 0] < sec.points[-1, 0]
    # the opposite normal gives the same curve
    np.testing.assert_allclose(plane_section(surf, (XC, 0.0, ZC), -np.array(n)).points,
                               sec.points, atol=1e-12)


def test_plane_section_of_the_marching_cubes_surface(mc_surfaces):
    *_, (surf, _) = mc_surfaces
    sec = plane_section(surf, (0.0, 0.0, ZC + 0.05))
    k = math.sqrt(1 - (0.05 / C) ** 2)
    p = sec.points
    q = (p - [XC, 0.0]) / [A * k, B * k]
    d = (np.sum(q**2, axis=1) - 1) / (2 * np.linalg.norm(q / [A * k, B * k], axis=1))
    assert np.abs(d[p[:, 1] > S]).max() <= 0.5 * S  # the surface's own half voxel
    assert p[0, 0] < XC < p[-1, 0]


def test_plane_section_agrees_with_the_2d_tracing_of_the_b_scan(mc_surfaces):
    # the B-scan k of the volume traced in 2D (imaging.mask_contour, as a 2D observation)
    # and the section of the volume's 3D surface at its z: the same curve within a voxel,
    # in the same order and orientation
    from bayescalib.geometry.imaging import mask_contour

    mask, org, _, (surf, _) = mc_surfaces
    k = 45
    traced = mask_contour(mask[k], S, (org[0], org[1]))
    sec = plane_section(surf, (0.0, 0.0, org[2] + k * S))
    d, _, _ = closest_points(sec.points, traced)
    assert np.abs(d[sec.points[:, 1] > S]).max() <= 0.5 * S
    assert np.abs(d).max() <= S
    for c in (traced, sec):
        assert c.points[0, 0] < XC < c.points[-1, 0]
        top = np.abs(c.centres[:, 0] - XC) < 0.1
        assert np.all(c.normals[top, 1] > 0.5)


def test_plane_section_errors():
    surf = half_ellipsoid_mesh(10, 30)
    with pytest.raises(SurfaceError, match="misses the surface"):
        plane_section(surf, (0.0, 0.0, ZC + 2 * C))
    with pytest.raises(SurfaceError, match="horizontal"):
        plane_section(surf, (0.0, 0.05, 0.0), (0.0, 1.0, 0.0))
    two = Interface.surface(np.vstack([surf.points, surf.points + [1.0, 0.0, 0.0]]),
                            np.vstack([surf.cells, surf.cells + surf.n_points]))
    with pytest.raises(SurfaceError, match="in 2 pieces"):
        plane_section(two, (0.0, 0.0, ZC))


# ------------------------------------------------------------------ surface operations
def test_colony_surface_cuts_orients_and_checks():
    closed = icosphere(0.2, 3).transformed(shift=[0.0, 0.1, 0.0])
    # cut at the floor y = 0: a cap, rim on the floor, normals out; reversed input flipped
    cap, info = colony_surface(closed.points, closed.cells[:, ::-1], floor=0.0)
    assert info["flipped"] and cap.points[:, 1].min() == pytest.approx(0.0, abs=1e-6)
    h = 0.3  # cap of height h of a sphere of radius R: V = pi h^2 (3R - h) / 3
    assert info["volume_mm3"] == pytest.approx(math.pi * h**2 * (0.6 - h) / 3, rel=0.02)
    with pytest.raises(SurfaceError, match="closed"):
        colony_surface(closed.points, closed.cells, floor=None)
    # a rim above the floor: cut off
    with pytest.raises(SurfaceError, match=r"rim vertices above the floor.*cut off"):
        colony_surface(cap.points, cap.cells, floor=-0.05)
    # Taubin keeps the rim on the floor plane
    x = taubin_smooth(cap.points, cap.cells, 10)
    rim = np.abs(cap.points[:, 1]) < 1e-9
    np.testing.assert_allclose(x[rim, 1], 0.0, atol=1e-12)


# ------------------------------------------------------------------ projection in 3D
def _brute_force_distance(q, p):
    """Distance of every query (k, 3) to every triangle (m, 3, 3), independently of
    Ericson's Voronoi regions: the foot of the perpendicular on the plane when its
    barycentric coordinates are >= 0, else the nearest of the three edges."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    out = np.empty((q.shape[0], p.shape[0]))
    for i, x in enumerate(q):
        foot = x - np.einsum("md,md->m", x - a, n)[:, None] * n
        e1, e2, r = b - a, c - a, foot - a  # barycentric coordinates from the Gram system
        g11, g12, g22 = (np.einsum("md,md->m", u, v) for u, v in ((e1, e1), (e1, e2), (e2, e2)))
        r1, r2 = np.einsum("md,md->m", r, e1), np.einsum("md,md->m", r, e2)
        det = g11 * g22 - g12**2
        lam = np.column_stack([(g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det])
        inside = (lam >= 0).all(axis=1) & (lam.sum(axis=1) <= 1)
        best = np.where(inside, np.linalg.norm(x - foot, axis=1), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            w = np.clip(np.einsum("md,md->m", x - u, v - u) / np.einsum("md,md->m", v - u, v - u),
                        0, 1)
            best = np.minimum(best, np.linalg.norm(x - (u + w[:, None] * (v - u)), axis=1))
        out[i] = best
    return out


def test_closest_points_3d_matches_brute_force():
    rng = np.random.default_rng(7)
    surf = half_ellipsoid_mesh(6, 16)
    q = np.column_stack([rng.uniform(0.0, 1.0, 60), rng.uniform(-0.1, 0.3, 60),
                         rng.uniform(0.0, 0.8, 60)])
    signed, y, _ = closest_points(q, surf)
    ref = _brute_force_distance(q, surf.points[surf.cells]).min(axis=1)
    np.testing.assert_allclose(np.abs(signed), ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q - y, axis=1), ref, rtol=1e-10, atol=1e-12)
    # the sign: outside the closed-by-the-floor colony positive
    outside = ellipsoid_distance(q) > 1e-3
    assert np.all(signed[outside & (q[:, 1] > 0)] > 0)


def test_closest_points_3d_analytic_plane_and_sphere():
    # a square [0, 1]^2 in z = 0 (normal +z): above its interior the distance is z, beyond
    # an edge sqrt(out^2 + z^2), exactly
    sq = square(1.0, 5)
    q = np.array([[0.3, 0.4, 0.2], [0.7, 0.1, -0.3], [1.5, 0.5, 0.4], [-0.3, -0.4, 0.1]])
    d, _, _ = closest_points(q, sq)
    np.testing.assert_allclose(d, [0.2, -0.3, math.hypot(0.5, 0.4), math.hypot(0.5, 0.1)],
                               rtol=1e-12)
    # a sphere of radius 1 (level-4 icosphere: flat facets lie inside by <= 1.3e-3)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    r = rng.uniform(0.5, 1.5, 200)
    d, _, _ = closest_points(u * r[:, None], icosphere(1.0, 4))
    np.testing.assert_allclose(d, r - 1.0, atol=1.5e-3)


# ------------------------------------------------------------------ files
def _polydata(surface):
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk

    pd = vtk.vtkPolyData()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(surface.points), deep=True))
    pd.SetPoints(pts)
    cells = vtk.vtkCellArray()
    for t in surface.cells:
        cells.InsertNextCell(3, [int(v) for v in t])
    pd.SetPolys(cells)
    return pd


def _write(path, surface, scale=1.0, ascii_=False, header=None):
    import vtk

    s = Interface.surface(surface.points * scale, surface.cells)
    pd = _polydata(s)
    suffix = path.suffix
    if suffix == ".stl":
        w = vtk.vtkSTLWriter()
        w.SetFileType(1 if ascii_ else 2)
        if header:
            w.SetHeader(header)
    elif suffix == ".ply":
        w = vtk.vtkPLYWriter()
        if header:
            w.AddComment(header)
    elif suffix == ".vtp":
        if header:
            arr = vtk.vtkStringArray()
            arr.SetName("unit")
            arr.InsertNextValue(header)
            pd.GetFieldData().AddArray(arr)
        w = vtk.vtkXMLPolyDataWriter()
    else:
        w = vtk.vtkPolyDataWriter()
        if header:
            w.SetHeader(header)
    w.SetFileName(str(path))
    w.SetInputData(pd)
    w.Write()
    return path


@pytest.mark.parametrize("name,ascii_", [("c.stl", True), ("c.stl", False), ("c.ply", False),
                                         ("c.vtp", False), ("c.vtk", False)])
def test_read_surface_formats_in_um(tmp_path, name, ascii_):
    surf = half_ellipsoid_mesh(12, 36)
    path = _write(tmp_path / name, surf, 1000.0, ascii_)
    got, info = read_surface(path, units="um")
    # STL stores float32: 1e-7 relative of 1000 um
    assert got.n_cells == surf.n_cells and info["units"] == "um"
    np.testing.assert_allclose(np.sort(got.points, axis=0), np.sort(surf.points, axis=0),
                               atol=1e-6)
    assert got.total_measure == pytest.approx(surf.total_measure, rel=1e-6)
    assert info["volume_mm3"] == pytest.approx(enclosed_volume(surf.points, surf.cells, 0.0),
                                               rel=1e-6)
    out = np.einsum("md,md->m", got.normals, got.centres - [XC, 0.0, ZC])
    assert np.all(out > 0)


@pytest.mark.parametrize("name,header", [("h.stl", "bayescalib colony, unit: um"),
                                         ("h.ply", "unit um"), ("h.vtp", "um"),
                                         ("h.vtk", "colony units=um")])
def test_read_surface_unit_from_header(tmp_path, name, header):
    surf = half_ellipsoid_mesh(8, 24)
    path = _write(tmp_path / name, surf, 1000.0, header=header)
    if name.endswith((".stl", ".ply", ".vtk")):
        assert header_units(path) == "um"
    got, info = read_surface(path)
    assert info["units"] == "um" and info["units_source"] == "header"
    assert got.bounds[1, 1] == pytest.approx(B, rel=1e-6)
    with pytest.raises(ObservationError, match="units='mm' but the file's header says 'um'"):
        read_surface(path, units="mm")


def test_read_surface_closed_file_cut_at_the_floor(tmp_path):
    # a closed colony with its flat base: floor='auto' cuts the base off
    surf = half_ellipsoid_mesh(12, 36)
    base = np.column_stack([np.arange(36), np.roll(np.arange(36), 1),
                            np.full(36, surf.n_points)])
    pts = np.vstack([surf.points, [XC, 0.0, ZC]])
    closed = Interface.surface(pts, np.vstack([surf.cells, base]))
    path = _write(tmp_path / "closed.stl", closed)
    with pytest.raises(ObservationError, match="closed"):
        read_surface(path, units="mm")
    got, info = read_surface(path, units="mm", floor="auto")
    assert got.total_measure == pytest.approx(surf.total_measure, rel=1e-4)
    assert info["floor_mm"] == pytest.approx(0.0, abs=1e-5)


def test_read_surface_refuses_bad_files(tmp_path):
    surf = half_ellipsoid_mesh(8, 24)
    path = _write(tmp_path / "c.stl", surf)
    with pytest.raises(ObservationError, match=r"c\.stl: no length unit.*units="):
        read_surface(path)
    with pytest.raises(ObservationError, match="unknown units 'cm'"):
        read_surface(path, units="cm")
    with pytest.raises(ObservationError, match="no such file"):
        read_surface(tmp_path / "missing.stl", units="mm")
    with pytest.raises(ObservationError, match="unknown surface file type '.obj'"):
        read_surface(tmp_path / "c.obj", units="mm")
    # a truncated binary STL
    cut = tmp_path / "cut.stl"
    cut.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(ObservationError, match="truncated or corrupt"):
        read_surface(cut, units="mm")
    # no triangles: an empty binary STL, and a VTK file with lines only
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"\0" * 80 + struct.pack("<I", 0))
    with pytest.raises(ObservationError, match="no points|no triangles"):
        read_surface(empty, units="mm")
    lines = tmp_path / "lines.vtk"
    lines.write_text("# vtk DataFile Version 3.0\nl\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
                     "0 0 0 1 0 0 1 1 0\nLINES 1 4\n3 0 1 2\n")
    with pytest.raises(ObservationError, match="no triangles or polygons"):
        read_surface(lines, units="mm")
    # two colonies: their number and areas, and how to pick one
    two = Interface.surface(np.vstack([surf.points, 0.5 * surf.points + [1.5, 0.0, 0.0]]),
                            np.vstack([surf.cells, surf.cells + surf.n_points]))
    p2 = _write(tmp_path / "two.ply", two)
    with pytest.raises(ObservationError, match=r"2 separate pieces.*mm\^2.*component=k"):
        read_surface(p2, units="mm")
    one, info = read_surface(p2, units="mm", component=0)
    assert info["components"] == 2 and one.total_measure == pytest.approx(surf.total_measure)
    # cut off: the top of the colony is missing (a hole)
    top = surf.centres[:, 1] > 0.9 * B
    holed = Interface.surface(surf.points, surf.cells[~top])
    with pytest.raises(ObservationError, match="cut off"):
        read_surface(_write(tmp_path / "holed.vtp", holed), units="mm")
    # a unit mismatch: um read as mm does not fit the 1 mm channel
    big = _write(tmp_path / "big.stl", surf, 1000.0)
    with pytest.raises(ObservationError, match="units='um'"):
        read_surface(big, units="mm", domain=[[0, 1], [0, 1], [0, 1]])

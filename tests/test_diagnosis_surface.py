"""The diagnosis's predictive check on 3D surfaces (``bayescalib.diagnosis.residuals``).

A half-ellipsoidal colony (semi-axes 0.3, 0.15, 0.25 mm) triangulated on an
(elevation, azimuth) grid stands for the model's interface; posterior draws are the same
surface scaled in height by a few um (all draws share their nodes, as the solves of one
mesh do); the observed nodes are a draw plus white noise, and, for a mismatch, a smooth
Gaussian bump of the normal offset on one flank. Tolerances are stated where they are
used.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.diagnosis.residuals import (
    colony_place,
    estimate_surface_noise,
    node_distances,
    predictive_check,
    smoother,
    surface_regions,
    thin_nodes,
)
from bayescalib.geometry.interface import Interface

A, B, C = 0.3, 0.15, 0.25
CENTRE = np.array([1.0, 0.0, 0.5])


def dome(n: int = 24, height: float = B) -> Interface:
    """The half-ellipsoid's surface, outward triangles; ``n`` elevation rings (the 3D
    model's reference surface of this colony)."""
    from bayescalib.models.fsi.geometry3d import reference_surface

    geometry = {"shape": "half_ellipse", "length": 2.0, "channel_height": 1.0,
                "channel_width": 1.0, "centre": CENTRE[0], "centre_z": CENTRE[2],
                "width": 2 * A, "height": height, "depth": 2 * C}
    return reference_surface(geometry, n)


def normals_at(points: np.ndarray, height: float = B) -> np.ndarray:
    """Unit outward normals of the half-ellipsoid at (near-surface) points."""
    g = (points - CENTRE) / np.array([A, height, C]) ** 2
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def draws(rng, K: int = 12, spread: float = 0.002) -> list[list[Interface]]:
    """K predicted surfaces (one snapshot each): heights B + N(0, spread) mm."""
    return [[dome(height=B + spread * rng.standard_normal())] for _ in range(K)]


def observed_nodes(rng, sigma: float, bump: float = 0.0, spacing: float = 0.02):
    """Observed nodes: a fine dome thinned to ``spacing``, above 10 um, pushed along
    the normal by white noise of sd ``sigma`` and a Gaussian bump of height ``bump`` (mm,
    width 0.06 mm) on the upstream flank."""
    fine = dome(n=48).points
    fine = fine[fine[:, 1] > 0.01]
    pts = fine[thin_nodes(fine, spacing)]
    at = CENTRE + np.array([-A * np.cos(0.6), B * np.sin(0.6), 0.0])
    shape = bump * np.exp(-0.5 * (np.linalg.norm(pts - at, axis=1) / 0.06) ** 2)
    return pts + (shape + sigma * rng.standard_normal(len(pts)))[:, None] * normals_at(pts), at


def test_thinned_surface_nodes_are_a_poisson_disk_subset():
    """Kept nodes are at least the spacing apart, and every node lies within the spacing
    of a kept one (the two properties of the greedy thinning, exactly)."""
    pts = dome(n=48).points
    keep = thin_nodes(pts, 0.03)
    d = node_distances(pts[keep])
    np.fill_diagonal(d, np.inf)
    assert d.min() >= 0.03 * (1 - 1e-9)
    to_kept = np.linalg.norm(pts[:, None, :] - pts[keep][None, :, :], axis=2).min(axis=1)
    assert to_kept.max() < 0.03
    assert 50 < keep.size < pts.shape[0] / 4
    np.testing.assert_array_equal(thin_nodes(pts, 0.0), np.arange(pts.shape[0]))


def test_surface_smoother_keeps_constants_and_smooths_noise():
    """Rows sum to 1 (a constant passes unchanged to round-off); white noise's sd drops
    by at least 3x at ell = 0.05 mm with nodes 0.02 mm apart (about 20 nodes within a
    kernel width: the variance falls ~20x, so 3x in sd is safe)."""
    rng = np.random.default_rng(0)
    pts, _ = observed_nodes(rng, 0.0)
    S = smoother(pts, 0.05)
    np.testing.assert_allclose(S @ np.full(len(pts), 0.7), 0.7, rtol=1e-12)
    e = rng.standard_normal(len(pts))
    assert np.std(S @ e) < np.std(e) / 3


def test_surface_noise_estimate_ignores_a_smooth_mismatch():
    """Noise of 2 um with a 15 um smooth bump: estimated within 20 % (about 300 nodes:
    the MAD's relative sd is ~1.1/sqrt(n) ~ 6 %; the bump's curvature adds a little)."""
    rng = np.random.default_rng(1)
    pts, at = observed_nodes(rng, 0.0)
    bump = 0.015 * np.exp(-0.5 * (np.linalg.norm(pts - at, axis=1) / 0.06) ** 2)
    y = bump + 0.002 * rng.standard_normal(len(pts))
    assert estimate_surface_noise(y, pts) == pytest.approx(0.002, rel=0.2)
    assert estimate_surface_noise(bump, pts) < 0.0008


def test_surface_regions_are_connected_pieces():
    """Two separate patches of marked nodes are two regions, the larger first."""
    pts, _ = observed_nodes(np.random.default_rng(2), 0.0)
    up = np.linalg.norm(pts - (CENTRE + [-A * 0.8, 0.05, 0.0]), axis=1) < 0.08
    down = np.linalg.norm(pts - (CENTRE + [A * 0.8, 0.05, 0.0]), axis=1) < 0.05
    pieces = surface_regions(up | down, pts)
    assert len(pieces) == 2
    assert set(pieces[0]) == set(np.flatnonzero(up))
    assert set(pieces[1]) == set(np.flatnonzero(down))
    assert surface_regions(np.zeros(len(pts), bool), pts) == []


def test_colony_place_in_words():
    pts = dome().points
    assert colony_place(CENTRE + [0, B, 0], pts) == "near the top"
    assert colony_place(CENTRE + [-A, 0.02, 0], pts) == "on the upstream flank, lower part"
    assert colony_place(CENTRE + [0.0, 0.09, C * 0.8], pts) == "on the side at +z flank, upper part"


def test_surface_check_passes_noise_and_locates_a_bump():
    """Noise alone (3 um, given): adequate. A 20 um bump on the upstream flank (about
    6 sd of the noise over a kernel width): inadequate, one region located around the
    bump: its core (the nodes of at least half the largest smoothed residual) centred
    within 0.03 mm (0.6 kernel widths) of the bump's centre, observed outside the
    prediction, in words on the upstream flank. (The peak of the *standardized*
    residual lies lower, where the draws' spread is smaller: not asserted.)"""
    rng = np.random.default_rng(3)
    dr = draws(rng)
    obs, _ = observed_nodes(rng, 0.003)
    null = predictive_check([obs], dr, sigma=0.003, rng=np.random.default_rng(4))
    assert null.adequate
    assert null.snapshots[0].s is None and null.snapshots[0].xy.shape[1] == 3
    obs, at = observed_nodes(rng, 0.003, bump=0.02)
    chk = predictive_check([obs], dr, sigma=0.003, rng=np.random.default_rng(4))
    assert not chk.adequate
    assert len(chk.located) >= 1
    loc = chk.located[0]
    core = obs[loc["core_node_indices"]]
    assert np.linalg.norm(core.mean(axis=0) - at) < 0.03
    assert loc["direction"].startswith("observed outside")
    assert "upstream" in loc["where"] and "upstream" in loc["core_where"]
    assert loc["core_node_indices"] and set(loc["core_node_indices"]) <= set(loc["node_indices"])
    assert chk.to_json()["located"][0]["n_nodes"] == loc["n_nodes"]


@pytest.mark.parametrize("noise_model", ["gaussian", "bootstrap"])
def test_surface_check_estimates_the_noise(noise_model):
    """sigma not given: estimated within 25 % of the 3 um noise by either noise model
    (gaussian: the neighbour-mean MAD; bootstrap: the RMS of the leave-one-out rough
    residuals, ~0.16 sigma^2 too large by construction, see the module docstring)."""
    rng = np.random.default_rng(5)
    obs, _ = observed_nodes(rng, 0.003)
    chk = predictive_check([obs], draws(rng), noise_model=noise_model,
                           rng=np.random.default_rng(6))
    assert chk.sigma == pytest.approx(0.003, rel=0.25)
    assert chk.sigma_source == "estimated"


def test_surface_residual_figure(tmp_path):
    """The 3D residual figure: one panel per snapshot and row, the located nodes ringed
    (a figure file per format; the colour bar names the band)."""
    from bayescalib.diagnosis.report import _panels
    from bayescalib.plotting.diagnosis import plot_surface_residuals

    rng = np.random.default_rng(3)
    dr = draws(rng)
    obs, _ = observed_nodes(rng, 0.003, bump=0.02)
    chk = predictive_check([obs], dr, sigma=0.003, rng=np.random.default_rng(4))
    panels = _panels(chk, chk.located)
    assert panels[0]["located"] and set(panels[0]["cores"]) <= set(panels[0]["located"])
    paths, fig = plot_surface_residuals(panels * 2, [tmp_path / "r.png", tmp_path / "r.pdf"],
                                        row_titles=["base", "extended"], return_figure=True)
    assert all(p.stat().st_size > 1000 for p in paths)
    assert "simultaneous band" in fig.axes[-1].get_xlabel()
    side = plot_surface_residuals(panels, tmp_path / "s.png", view="side")
    assert side[0].exists()
    with pytest.raises(ValueError, match="view"):
        plot_surface_residuals(panels, tmp_path / "x.png", view="front")


def test_a_volume_surface_is_used_one_voxel_above_its_cut():
    """The diagnosis leaves out the layer of voxels above a volume's cut (the foot the
    segmentation widens: rim_height); other surfaces are used whole; the thinning grows
    its spacing until at most MAX_SURFACE_NODES remain."""
    from bayescalib.diagnosis import context

    surf = dome(n=48)
    rec = {"kind": "volume", "floor": {"y_mm": 0.012}, "voxel_size_mm": [0.006, 0.006, 0.008]}
    assert context.rim_height(surf, rec) == pytest.approx(0.018)
    assert context.rim_height(surf, {"kind": "surface", "floor_mm": 0.012}) is None
    assert context.rim_height(surf, None) is None
    nodes, h = context.surface_nodes(surf, 0.02, 0.018)
    assert nodes[:, 1].min() >= 0.018 and h == 0.02
    whole, _ = context.surface_nodes(surf, 0.02)
    assert whole[:, 1].min() == pytest.approx(0.0) and len(whole) > len(nodes)
    few, h = context.surface_nodes(surf, 0.001)
    assert len(few) <= context.MAX_SURFACE_NODES < len(surf.points) and h > 0.001

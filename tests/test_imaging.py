"""Synthetic OCT-like images of an interface (bayescalib.geometry.imaging.render_mask):
a rendered, segmented and re-traced curve must come back within one pixel, the render
must be reproducible from its seed, and observations read from such masks through the
pipeline's observation stage must give back the curve and a noise level, estimated
from the data, of the size of the segmentation error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bayescalib.diagnosis.residuals import estimate_noise, offsets, predictive_check
from bayescalib.diagnosis.stage import (
    IMAGE_NOISE_LAG_PIXELS,
    noise_lag,
    resolve_noise_model,
    thinned_observations,
)
from bayescalib.geometry.imaging import mask_contour, pixel_grid, render_mask, render_scan
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.io.observations import read_interface, write_mask_png

S = 0.005  # pixel size, mm (5 um, an OCT scan)
#: moderate speckle: 16 looks (intensity sd 0.25 of the contrast), 1 pixel PSF and pre-smoothing
MODERATE = {"looks": 16.0, "noise": 0.05, "psf_sigma": 1.0, "smooth": 1.0}
NONE = {"looks": None, "noise": 0.0, "psf_sigma": 1.0, "smooth": 1.0}
#: the concealed benchmark's image mode (benchmarks/concealed.py): 4-look speckle
BENCHMARK = {"looks": 4.0, "noise": 0.05, "psf_sigma": 1.0, "smooth": 1.0}


def disc(r=0.2, centre=(0.5, 0.3), n=400) -> Interface:
    """Closed clockwise circle: the biofilm inside, normals outward."""
    t = -np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return Interface.polyline(np.column_stack([centre[0] + r * np.cos(t), centre[1] + r * np.sin(t)]),
                              closed=True)


def bump(height=0.12, width=0.12, n=400) -> Interface:
    """Gaussian bump on the floor y = 0, upstream to downstream (biofilm below)."""
    x = np.linspace(0.2, 1.0, n)
    y = height * np.exp(-0.5 * ((x - 0.6) / width) ** 2)
    y[[0, -1]] = 0.0
    return Interface.polyline(np.column_stack([x, y]))


def _centroid(points: np.ndarray) -> np.ndarray:
    """Centroid of the polygon closed by the chord from the last to the first point, mm."""
    x, y = points[:, 0], points[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    a = 0.5 * np.sum(cross)
    return np.array([np.sum((x + np.roll(x, -1)) * cross), np.sum((y + np.roll(y, -1)) * cross)]) / (6 * a)


def _grid(curve: Interface, on_floor: bool):
    return pixel_grid(curve.bounds, S, margin=0.03, floor=0.0 if on_floor else None)


def _retrace(curve: Interface, on_floor: bool, seed: int, **render) -> tuple[Interface, np.ndarray]:
    shape, origin = _grid(curve, on_floor)
    mask = render_mask(curve.points, pixel_size=S, origin=origin, shape=shape,
                       rng=np.random.default_rng(seed), **render)
    traced = mask_contour(mask, S, origin)
    d, _, _ = closest_points(traced.points, curve)
    return traced, d


@pytest.mark.parametrize("render", [NONE, MODERATE], ids=["clean", "speckle"])
@pytest.mark.parametrize("shape", ["disc", "bump"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rendered_curve_is_traced_back_within_one_pixel(shape, render, seed):
    curve, on_floor = (disc(), False) if shape == "disc" else (bump(), True)
    traced, d = _retrace(curve, on_floor, seed, **render)
    assert np.max(np.abs(d)) < S, f"max distance {np.max(np.abs(d)) / S:.2f} px"
    # no bias and no shift: a slip of the pixel convention by half a pixel moves the mean
    # offset (a shift in y on the bump) or the centroid (a shift in x, in y on the disc)
    assert abs(np.mean(d)) < 0.1 * S
    # (the traced bump stops at the bottom pixel row, y = s/2, so only its x is compared)
    axes = slice(0, 2) if shape == "disc" else slice(0, 1)
    np.testing.assert_allclose(_centroid(traced.points)[axes], _centroid(curve.points)[axes],
                               atol=0.25 * S)
    # the whole curve is there: a closed disc, an open bump ending next to the floor
    if shape == "disc":
        assert traced.n_cells == traced.n_points
        assert np.ptp(traced.points[:, 0]) == pytest.approx(0.4, abs=2 * S)
    else:
        assert traced.n_cells == traced.n_points - 1
        np.testing.assert_allclose(traced.points[[0, -1], 1], 0.5 * S)  # bottom pixel row
        assert traced.points[0, 0] < traced.points[-1, 0]  # upstream to downstream
        assert traced.normals[np.argmax(traced.centres[:, 1]), 1] > 0  # into the fluid


def test_the_biofilm_is_on_the_right_of_the_curve():
    """The same points traversed the other way bound the fluid: the mask is inverted."""
    c = disc()
    shape, origin = _grid(c, False)
    kw = {"pixel_size": S, "origin": origin, "shape": shape, **NONE}
    inside = render_mask(c.points, rng=np.random.default_rng(0), **kw)
    outside = render_mask(c.points[::-1], rng=np.random.default_rng(0), **kw)
    area = inside.sum() * S**2
    assert area == pytest.approx(np.pi * 0.2**2, rel=0.01)
    np.testing.assert_array_equal(outside, ~inside)


def test_the_scan_has_the_contrast_and_speckle_asked_for():
    c = disc(r=0.3, centre=(0.4, 0.4))
    shape, origin = _grid(c, False)
    img = render_scan(c.points, pixel_size=S, origin=origin, shape=shape,
                      rng=np.random.default_rng(0), looks=4.0, noise=0.05)
    rows, cols = np.indices(shape)
    x, y = origin[0] + cols * S, origin[1] + (shape[0] - 1 - rows) * S
    r = np.hypot(x - 0.4, y - 0.4)
    film, fluid = img[r < 0.25], img[r > 0.35]
    assert film.mean() == pytest.approx(1.0, abs=0.02)
    assert film.std() == pytest.approx(np.hypot(0.5, 0.05), rel=0.1)  # 1/sqrt(looks)
    assert fluid.mean() == pytest.approx(0.0, abs=0.01)
    assert fluid.std() == pytest.approx(0.05, rel=0.1)


def test_the_render_is_fixed_by_its_seed():
    c = bump()
    shape, origin = _grid(c, True)
    kw = {"pixel_size": S, "origin": origin, "shape": shape, **BENCHMARK}
    a = render_mask(c.points, rng=np.random.default_rng(5), **kw)
    b = render_mask(c.points, rng=np.random.default_rng(5), **kw)
    other = render_mask(c.points, rng=np.random.default_rng(6), **kw)
    np.testing.assert_array_equal(a, b)
    assert np.count_nonzero(a != other) > 0
    sa = render_scan(c.points, rng=np.random.default_rng(5), pixel_size=S, origin=origin,
                     shape=shape, looks=4.0)
    sb = render_scan(c.points, rng=np.random.default_rng(6), pixel_size=S, origin=origin,
                     shape=shape, looks=4.0)
    assert not np.allclose(sa, sb)


@pytest.mark.parametrize(
    "kwargs, match",
    [({"pixel_size": 0.0}, "pixel_size"), ({"psf_sigma": -1.0}, "psf_sigma"),
     ({"looks": 0.0}, "looks"), ({"noise": -0.1}, "noise"), ({"shape": (1, 10)}, "shape"),
     ({"threshold": "median"}, "threshold"), ({"min_size": -1}, "min_size")],
)
def test_bad_render_settings_are_named(kwargs, match):
    c = disc()
    shape, origin = _grid(c, False)
    kw = {"pixel_size": S, "origin": origin, "shape": shape, "rng": np.random.default_rng(0),
          **kwargs}
    with pytest.raises(ValueError, match=match):
        render_mask(c.points, **kw)


# ------------------------------------------------------- through the observation stage
def _analytic(params, factors=(0.5, 1.0)) -> list[Interface]:
    from bayescalib.models.analytic import interface

    out = []
    for f in factors:
        rec = interface({**params, "V": 100.0 * f})
        out.append(Interface.polyline(rec["current"]))
    return out


def _observe_masks(tmp_path, curves, seed=7, units="mm"):
    """Masks of ``curves`` written as the benchmark does, read by the observation stage
    from an ``observations: {source: files}`` section with pixel_size and origin."""
    from bayescalib.io.observation_store import read_observations
    from bayescalib.stages.observe import observe

    f = {"mm": 1.0, "um": 1.0e3}[units]
    rng = np.random.default_rng(seed)
    files = []
    for k, c in enumerate(curves):
        shape, origin = pixel_grid(c.bounds, S, margin=0.05, floor=0.0)
        mask = render_mask(c.points, pixel_size=S, origin=origin, shape=shape, rng=rng, **BENCHMARK)
        path = tmp_path / f"load_{k}.png"
        side = write_mask_png(path, mask, pixel_size=S * f, origin=[v * f for v in origin],
                              units=units)
        assert side.name == f"load_{k}.png.json"
        files.append({"path": str(path), "label": f"load_{k}", "load": None, "units": units,
                      "pixel_size": S * f, "origin": [v * f for v in origin]})
    section = {"source": "files", "files": files, "domain": [[0.0, 2.0], [0.0, 1.0]]}
    observe(section, tmp_path / "observations.h5")
    return section, read_observations(tmp_path / "observations.h5")


@pytest.mark.parametrize("units", ["mm", "um"])
def test_masks_read_through_the_observation_stage_give_back_the_curve(tmp_path, units):
    truth = _analytic({"E": 400.0, "nu": 0.3})
    _, obs = _observe_masks(tmp_path, truth, units=units)
    assert obs.labels == ["load_0", "load_1"]
    for snap, c in zip(obs.snapshots, truth, strict=True):
        d, _, _ = closest_points(np.asarray(snap.points), c)
        # 4-look speckle (the benchmark's): within 2 pixels everywhere, 0.5 px RMS
        assert np.max(np.abs(d)) < 2 * S
        assert np.sqrt(np.mean(d**2)) < 0.5 * S
        assert np.asarray(snap.points).shape[0] > 200  # about one node per pixel of arc
    # the sidecar says how to read the mask back
    side = json.loads((tmp_path / "load_1.png.json").read_text())
    assert side["pixel_size_mm"] == S and side["units"] == units
    back = read_interface(tmp_path / "load_1.png", units=units, pixel_size=side["pixel_size"],
                          origin=side["origin"])
    np.testing.assert_allclose(back.points, obs.snapshots[1].points)


def test_the_noise_level_is_estimated_from_the_masks(tmp_path):
    """The diagnosis's noise level for image data comes from the residual, at a lag of
    5 pixels: it must match the segmentation error actually in the data.

    Tolerance 35 %: the estimate is a MAD of a correlated, quantised error over ~250
    nodes per snapshot (measured 0.9-1.3 x the RMS over seeds and loadings); the lag-1
    estimate collapses on such data (nodes on pixel edges share quantisation steps)."""
    truth = _analytic({"E": 400.0, "nu": 0.3})
    section, obs = _observe_masks(tmp_path, truth)
    lag = noise_lag({"noise_lag": None}, section)
    assert lag == pytest.approx(IMAGE_NOISE_LAG_PIXELS * S)
    assert noise_lag({"noise_lag": None}, {**section, "files": [
        {**e, "units": "um", "pixel_size": 5.0} for e in section["files"]]}) == pytest.approx(lag)
    assert noise_lag({"noise_lag": 0.01}, section) == 0.01
    assert noise_lag({"noise_lag": None}, {"source": "synthetic"}) == 0.0
    # and resamples its noise from the data (the segmentation error is not Gaussian)
    assert resolve_noise_model({"noise_model": None, "smoothing": 0.05}, section) == "bootstrap"
    assert resolve_noise_model({"noise_model": None, "smoothing": 0.0}, section) == "gaussian"
    assert resolve_noise_model({"noise_model": None}, {"source": "synthetic"}) == "gaussian"
    assert resolve_noise_model({"noise_model": "gaussian"}, section) == "gaussian"
    # the diagnosis uses nodes one lag apart (the error's correlation length)
    used = thinned_observations(obs, lag)
    for full, thin in zip(obs.snapshots, used.snapshots, strict=True):
        step = np.linalg.norm(np.diff(thin.points, axis=0), axis=1)
        assert np.all(step < lag + 2 * S) and np.median(step) == pytest.approx(lag, abs=S)
        assert len(thin.points) < len(full.points) / 5
        np.testing.assert_array_equal(thin.points[[0, -1]], full.points[[0, -1]])
    # posterior draws of a well-calibrated model: the truth with E a little off
    draws = [_analytic({"E": e, "nu": 0.3}) for e in (396.0, 398.0, 400.0, 402.0, 404.0)]
    chk = predictive_check(used.snapshots, draws, labels=used.labels, sigma=None, noise_lag=lag,
                           rng=np.random.default_rng(0))
    err = np.concatenate([offsets(np.asarray(s.points), c, [])[0]
                          for s, c in zip(obs.snapshots, truth, strict=True)])
    rms = float(np.sqrt(np.mean(err**2)))
    assert 0.2 * S < rms < 0.5 * S  # a fraction of a pixel: 1-2.5 um
    assert chk.sigma_source == "estimated"
    assert chk.to_json()["noise_lag_mm"] == pytest.approx(lag)
    assert chk.sigma == pytest.approx(rms, rel=0.35)
    old = np.median([estimate_noise(offsets(np.asarray(s.points), c, [])[0])
                     for s, c in zip(obs.snapshots, truth, strict=True)])
    assert old < 0.2 * rms


def test_thinning_keeps_one_node_per_spacing():
    from bayescalib.diagnosis.residuals import thin_nodes

    pts = np.column_stack([np.linspace(0.0, 1.0, 101), np.zeros(101)])  # 0.01 mm apart
    np.testing.assert_array_equal(thin_nodes(pts, 0.0), np.arange(101))
    idx = thin_nodes(pts, 0.025)
    assert idx[0] == 0 and idx[-1] == 100
    # the first node at or beyond each multiple of 0.025 mm: 0, 0.03, 0.05, 0.08, 0.1, ...
    x = pts[idx[:-1], 0]
    assert np.all(x >= np.arange(len(x)) * 0.025 - 1e-12)
    assert np.all(x < np.arange(len(x)) * 0.025 + 0.01)
    assert len(idx) == 41
    with pytest.raises(ValueError, match="spacing"):
        thin_nodes(pts, -1.0)


# ------------------------------------------------------------------- the workflow
IMAGE_STUDY = {
    "study": "analytic_images",
    "forward_model": {"type": "python", "time_limit_s": 60,
                      "python": {"function": "bayescalib.models.analytic:interface"},
                      "loadings": {"parameter": "V", "nominal": 100.0, "factors": [0.5, 1.0]}},
    "parameters": [
        {"name": "E", "unit": "Pa", "target": "E", "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0},
         "bounds": [100.0, 800.0], "ground_truth": 400.0},
        {"name": "nu", "unit": "-", "target": "nu", "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45},
         "bounds": [-0.8, 0.45], "ground_truth": 0.3}],
    "measures": ["cpp"],
    # sigma_N = 2 um: the masks' segmentation error is 1.5-2.2 um RMS (0.3-0.45 pixel)
    "likelihood": {"sigma_n2": 4.0e-6},
    "design": {"strategy": "fixed", "n_train": 32, "seed": 1},
    "surrogate": {"restarts": 1},
    "smc": {"n_particles": 500, "n_rej": 3, "zeta": 0.9, "seed": 0},
    "plots": {"n_interface_samples": 2, "formats": ["png"], "dpi": 60, "grid": 20, "fields": False},
    "diagnose": {"enabled": True, "n_draws": 8, "n_extend": 0,
                 "candidates": [{"name": "base_slip", "target": "base_slip", "step": 0.005,
                                 "prior": [0.0, 0.03], "unit": "mm",
                                 "summary": "base slides downstream"}]},
}


@pytest.mark.workflow
@pytest.mark.extended
def test_the_diagnosis_of_a_study_observed_as_masks_estimates_the_noise(tmp_path):
    """Masks of the analytic model's truth at two loadings, read by a files-sourced study
    (pixel_size, origin): the diagnosis must estimate the noise from them (not take a
    generator's value), at the segmentation error's size, on nodes one lag apart, with
    replicates resampled from the residual (the bootstrap noise model), and claim
    nothing."""
    from _workflow_helpers import setup_study, smk

    truth = _analytic({"E": 400.0, "nu": 0.3})
    section, obs = _observe_masks(tmp_path, truth)
    err = np.concatenate([offsets(np.asarray(s.points), c, [])[0]
                          for s, c in zip(obs.snapshots, truth, strict=True)])
    rms = float(np.sqrt(np.mean(err**2)))
    setup_study(tmp_path, {**IMAGE_STUDY, "observations": section})
    smk(tmp_path)
    root = tmp_path / "results" / "analytic_images"
    d = json.loads((root / "diagnosis" / "diagnosis.json").read_text())
    assert d["check"]["sigma_source"] == "estimated"
    assert d["check"]["noise_model"]["name"] == "bootstrap"
    assert d["check"]["noise_model"]["pool"]["n"] == d["check"]["statistics"]["n_nodes"]
    assert d["check"]["noise_lag_mm"] == pytest.approx(IMAGE_NOISE_LAG_PIXELS * S)
    assert d["check"]["sigma_mm"] == pytest.approx(rms, rel=0.35)
    nodes = d["observed_nodes"]
    assert nodes["spacing_mm"] == pytest.approx(IMAGE_NOISE_LAG_PIXELS * S)
    assert nodes["n_observed"] == [len(s.points) for s in obs.snapshots]
    assert all(u < n / 5 for u, n in zip(nodes["n_used"], nodes["n_observed"], strict=True))
    assert d["check"]["statistics"]["n_nodes"] == sum(nodes["n_used"])
    # nothing is hidden in the masks: no candidate physics may be claimed
    assert d["attribution"]["selected"] == [] and d["chosen_model"] == "base"
    assert not d["verdict"].startswith("mismatch explained")

"""Raw greyscale scans as observations (bayescalib.geometry.imaging.read_mask): a scan is
segmented by the tool, a two-valued image is a mask, the substrate line is found, huge
images are refused from their header, and the segmentation states its own positional
uncertainty of the interface."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from skimage import io

from bayescalib.geometry.imaging import (
    ImageError,
    load_mask,
    mask_contour,
    pixel_grid,
    read_mask,
    render_scan,
)
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.io.observations import ObservationError, read_interface, read_interface_info

S = 0.005  # pixel size, mm


def bump(height=0.12, width=0.12, n=400) -> Interface:
    """Gaussian bump on the floor y = 0 (biofilm below), upstream to downstream."""
    x = np.linspace(0.2, 1.0, n)
    y = height * np.exp(-0.5 * ((x - 0.6) / width) ** 2)
    y[[0, -1]] = 0.0
    return Interface.polyline(np.column_stack([x, y]))


def _scan(curve, seed=0, looks=16.0, noise=0.05, floor=0.0, margin=0.03):
    shape, origin = pixel_grid(curve.bounds, S, margin=margin, floor=floor)
    img = render_scan(curve.points, pixel_size=S, origin=origin, shape=shape,
                      rng=np.random.default_rng(seed), looks=looks, noise=noise)
    return img, shape, origin


def _to_bits(img, bits):
    """Contrast 1 -> 40 % of the range, fluid at 15 %: a scan in its own intensity scale."""
    top = 2**bits - 1
    return np.clip(np.rint((0.15 + 0.4 * img) * top), 0, top).astype(np.uint8 if bits == 8
                                                                        else np.uint16)


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_raw_scan_is_segmented_to_the_interface_within_a_pixel(tmp_path, bits, seed):
    curve = bump()
    img, shape, origin = _scan(curve, seed)
    path = tmp_path / f"scan{bits}.png"
    io.imsave(path, _to_bits(img, bits), check_contrast=False)
    mask, info = read_mask(path)
    assert info["kind"] == "scan" and info["bit_depth"] == bits
    assert info["shape"] == list(shape) and info["threshold_method"] == "otsu"
    # the threshold is in the file's own scale, between the fluid and the biofilm level
    top = 2**bits - 1
    assert 0.15 * top < info["threshold"] < 0.55 * top
    traced = mask_contour(mask, S, origin)
    d, _, _ = closest_points(traced.points, curve)
    assert np.max(np.abs(d)) < 1.0 * S, f"max {np.max(np.abs(d)) / S:.2f} px"
    assert abs(np.mean(d)) < 0.15 * S
    # through the reader, with the same result
    back = read_interface(path, pixel_size=S, origin=origin)
    np.testing.assert_allclose(back.points, traced.points)


def test_an_rgb_scan_uses_its_first_channel_and_a_given_threshold(tmp_path):
    img, _, _ = _scan(bump())
    grey = _to_bits(img, 8)
    rgb = np.stack([grey, np.zeros_like(grey), np.full_like(grey, 255)], axis=-1)
    io.imsave(tmp_path / "rgb.png", rgb, check_contrast=False)
    mask, info = read_mask(tmp_path / "rgb.png", segmentation={"threshold": 0.35 * 255})
    assert info["channels"] == 3 and info["threshold"] == pytest.approx(0.35 * 255)
    assert info["threshold_method"] == "given"
    np.testing.assert_array_equal(mask, read_mask(tmp_path / "rgb.png", image="scan",
                                                  segmentation={"threshold": 89.25})[0])


def test_two_grey_values_are_a_mask_anything_else_a_scan(tmp_path):
    rows, cols = np.mgrid[0:60, 0:80]
    m = (cols - 40) ** 2 + (rows - 59) ** 2 <= 20**2
    io.imsave(tmp_path / "mask.png", np.where(m, 200, 30).astype(np.uint8), check_contrast=False)
    mask, info = read_mask(tmp_path / "mask.png")
    assert info["kind"] == "mask" and info["sigma_px"] is None  # no intensity: no estimate
    np.testing.assert_array_equal(mask, m)
    np.testing.assert_array_equal(load_mask(tmp_path / "mask.png"), m)  # the old reader
    img, _, _ = _scan(bump())
    io.imsave(tmp_path / "scan.tif", _to_bits(img, 16), check_contrast=False)
    assert read_mask(tmp_path / "scan.tif")[1]["kind"] == "scan"
    # forced: the same mask segmented as a scan keeps its shape (specks aside)
    as_scan, info = read_mask(tmp_path / "mask.png", image="scan")
    assert info["kind"] == "scan" and np.mean(as_scan != m) < 0.01
    with pytest.raises(ValueError, match="image must be"):
        read_mask(tmp_path / "mask.png", image="photo")


@pytest.mark.parametrize("value", [0, 255])
def test_an_all_black_or_all_white_image_is_refused_naming_the_file(tmp_path, value):
    io.imsave(tmp_path / "flat.png", np.full((40, 40), value, np.uint8), check_contrast=False)
    with pytest.raises(ImageError, match=r"flat\.png: .*single grey value.*all black or all white"):
        read_mask(tmp_path / "flat.png")


def test_a_scan_without_biofilm_at_the_given_threshold_is_refused(tmp_path):
    img, _, _ = _scan(bump())
    io.imsave(tmp_path / "scan.png", _to_bits(img, 8), check_contrast=False)
    with pytest.raises(ImageError, match=r"scan\.png: the segmentation of the scan finds no "
                                         r"foreground.*threshold 250"):
        read_mask(tmp_path / "scan.png", segmentation={"threshold": 250})
    with pytest.raises(ImageError, match=r"scan\.png: .*finds no background"):
        read_mask(tmp_path / "scan.png", segmentation={"threshold": -1, "min_size": 0})


def _png_header(width, height):
    """A PNG claiming ``width`` x ``height`` 8-bit grey pixels whose data is 20 bytes of an
    empty stream: decoding it would allocate the claimed size."""

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
            + chunk(b"IEND", b""))


def test_a_huge_image_is_refused_from_its_header_before_decoding(tmp_path):
    (tmp_path / "bomb.png").write_bytes(_png_header(20_000, 5_000))
    with pytest.raises(ImageError, match=r"bomb\.png: the image is 20000 x 5000 pixels "
                                         r"\(100\.0 megapixels\), more than the limit of 50"):
        read_mask(tmp_path / "bomb.png")
    with pytest.raises(ObservationError, match=r"bomb\.png: .*megapixels.*before decoding"):
        read_interface(tmp_path / "bomb.png", pixel_size=S, origin=(0, 0))
    # beyond Pillow's own bomb limit (179 megapixels) the header still names the size
    (tmp_path / "bigger.png").write_bytes(_png_header(100_000, 80_000))
    with pytest.raises(ImageError, match=r"bigger\.png: the image header declares 8000\.0 "
                                         r"megapixels, more than the limit"):
        read_mask(tmp_path / "bigger.png")
    # a moderate image above a lowered limit
    io.imsave(tmp_path / "big.png", np.tile(np.uint8([0, 255]), (200, 150)), check_contrast=False)
    with pytest.raises(ImageError, match=r"big\.png: the image is 300 x 200 pixels"):
        read_mask(tmp_path / "big.png", max_pixels=50_000)
    assert read_mask(tmp_path / "big.png", max_pixels=60_000)[1]["shape"] == [200, 300]


def test_the_floor_is_found_as_a_bright_band_or_the_bottom_of_the_foreground(tmp_path):
    """Colonies on a bright substrate reflection (the OCT floor, 4 rows at 2.5x the
    biofilm's intensity, with glass below): floor auto cuts at the band's top edge and
    keeps the colony's surface; colonies on a dark floor: the bottom of the foreground."""
    curve = bump()
    floor_y = 0.05  # the substrate's top, mm: 10 rows of glass below it
    shifted = Interface.polyline(curve.points + [0.0, floor_y])
    img, shape, origin = _scan(shifted, floor=0.0, looks=None)
    h = shape[0]
    rows = np.arange(h)
    y = origin[1] + (h - 1 - rows) * S
    band = (y < floor_y) & (y > floor_y - 4 * S)
    img[band, :] += 2.5
    path = tmp_path / "oct.png"
    io.imsave(path, _to_bits(img / 3.0, 8), check_contrast=False)
    _, info = read_mask(path)
    assert info["floor"]["method"] == "bright band"
    # the band's top edge, raised over its blurred halo (about 2 rows here)
    edge_y = origin[1] + (h - 1 - info["floor"]["row"]) * S
    assert floor_y <= edge_y <= floor_y + 3 * S
    # half the biofilm's contrast (Otsu's threshold, pulled up by the bright band's
    # pixels, would trace the colony ~0.8 pixel inside)
    half = {"threshold": (0.15 + 0.5 * 0.4 / 3.0) * 255}
    c, ci = read_interface_info(path, pixel_size=S, origin=origin, floor="auto",
                                segmentation=half)
    assert ci["floor_mm"] == pytest.approx(edge_y, abs=S) and ci["floor_source"] == "auto"
    assert c.points[:, 1].min() > ci["floor_mm"]  # nothing of the substrate line is left
    d, _, _ = closest_points(c.points, shifted)
    # within a pixel on the colony, 3 where it meets the band's halo
    assert np.sqrt(np.mean(d**2)) < 0.5 * S and np.max(np.abs(d)) < 3 * S
    # the colony, not a piece of the floor (its tails thinner than the halo are cut)
    assert c.points[:, 1].max() == pytest.approx(floor_y + 0.12, abs=S)
    assert np.ptp(c.points[:, 0]) > 0.4
    # without the cut, the longest contour runs along the substrate
    whole = read_interface(path, pixel_size=S, origin=origin, segmentation=half)
    assert whole.points[:, 1].min() <= ci["floor_mm"] + 0.5 * S
    # a dark floor (substrate segmented as background): the bottom of the foreground
    img2, shape2, origin2 = _scan(shifted, floor=0.0, looks=None)
    io.imsave(tmp_path / "dark.png", _to_bits(img2, 8), check_contrast=False)
    _, info2 = read_mask(tmp_path / "dark.png")
    assert info2["floor"]["method"] == "foreground bottom"
    assert origin2[1] + (shape2[0] - 1 - info2["floor"]["row"]) * S == pytest.approx(floor_y,
                                                                                      abs=S)
    # the biofilm on the image's bottom edge: nothing to cut
    img3, _, origin3 = _scan(curve)
    io.imsave(tmp_path / "edge.png", _to_bits(img3, 8), check_contrast=False)
    _, i3 = read_interface_info(tmp_path / "edge.png", pixel_size=S, origin=origin3,
                                 floor="auto")
    assert i3["floor"] == {"method": "image bottom", "row": None} and i3["floor_mm"] is None


def test_a_thin_full_width_band_of_a_mask_is_the_floor(tmp_path):
    rows, cols = np.mgrid[0:80, 0:120]
    m = ((cols - 60) ** 2 + (rows - 70) ** 2 <= 25**2) | ((rows >= 70) & (rows < 73))
    io.imsave(tmp_path / "m.png", (m * 255).astype(np.uint8), check_contrast=False)
    _, info = read_mask(tmp_path / "m.png")
    assert info["floor"] == {"method": "full-width band", "row": 69.5}
    c = read_interface(tmp_path / "m.png", pixel_size=1.0, origin=(0, 0), floor="auto")
    assert c.points[:, 1].min() > 79 - 69.5  # above the band's top edge
    assert np.ptp(c.points[:, 0]) == pytest.approx(50, abs=2)


def test_the_segmentation_uncertainty_matches_the_edge_localisation_formula(tmp_path):
    """Known answer: a straight edge (biofilm below y = 0.1 mm), a Gaussian PSF of p = 1
    pixel, additive white noise of sd n (no speckle), pre-filter s = 1.5 pixels. The
    smoothed edge is an error function of width sqrt(p^2 + s^2), its slope at the
    half-contrast threshold is C / (sqrt(2 pi) sqrt(p^2 + s^2)), and the smoothed noise
    has sd n k, k = sqrt(sum of the squared kernel weights) ~ 1 / (2 sqrt(pi) s), so the
    crossing moves by n k sqrt(2 pi) sqrt(p^2 + s^2) / C pixels (sd).

    Tolerance 20 %: the noise sd is estimated from ~2000 pixels (a few % sampling error),
    the gradient is taken at the pixels next to the crossing (up to half a pixel off its
    peak: -4 %) by central differences (-5 %), and the 8-bit rounding adds noise
    (1/sqrt(12) grey values on 4)."""
    from scipy.ndimage import gaussian_filter

    line = np.array([[1.1, 0.1], [0.0, 0.1], [0.0, 0.0], [1.1, 0.0]])  # biofilm below
    shape, origin = (60, 220), (0.0025, 0.0025)
    contrast, n = 100.0, 8.0  # grey values
    img = render_scan(line, pixel_size=S, origin=origin, shape=shape,
                      rng=np.random.default_rng(3), psf_sigma=1.0, looks=None,
                      noise=n / contrast)
    io.imsave(tmp_path / "edge.png", np.clip(np.rint(60 + contrast * img), 0, 255)
              .astype(np.uint8), check_contrast=False)
    _, info = read_mask(tmp_path / "edge.png", segmentation={"smooth": 1.5})
    delta = np.zeros((31, 31))
    delta[15, 15] = 1.0
    k = np.sqrt(np.sum(gaussian_filter(delta, 1.5, mode="constant") ** 2))
    expected = n * k * np.sqrt(2 * np.pi) * np.hypot(1.0, 1.5) / contrast
    assert info["sigma_noise_px"] == pytest.approx(expected, rel=0.2)
    assert info["noise_sd"] == pytest.approx(n, rel=0.1)
    assert info["sigma_quantisation_px"] == pytest.approx(1 / np.sqrt(12))
    assert info["sigma_px"] == pytest.approx(np.hypot(info["sigma_noise_px"], 1 / np.sqrt(12)))
    # in mm through the reader
    _, ri = read_interface_info(tmp_path / "edge.png", pixel_size=5.0, units="um",
                                origin=(2.5, 2.5), segmentation={"smooth": 1.5})
    assert ri["sigma_mm"] == pytest.approx(info["sigma_px"] * S)


def test_the_segmentation_uncertainty_is_the_size_of_the_traced_error():
    """Speckled scans (4 looks): the stated uncertainty is of the size of the traced
    interface's RMS error against the truth (measured 0.37 vs 0.42 px; within 35 %)."""
    from bayescalib.geometry.imaging import _positional_sigma, _segment

    curve = bump()
    errs, sig = [], []
    for seed in range(3):
        img, _, origin = _scan(curve, seed, looks=4.0)
        mask, sm, _ = _segment(img, smooth=1.5, threshold="otsu", min_size=64)
        d, _, _ = closest_points(mask_contour(mask, S, origin).points, curve)
        errs.append(np.sqrt(np.mean(d**2)) / S)
        sig.append(_positional_sigma(img, sm, mask, 1.5)["sigma_px"])
    assert np.mean(sig) == pytest.approx(np.mean(errs), rel=0.35)


# ------------------------------------------------ observation store, diagnosis, figure
def _files_section(tmp_path, n=2):
    """Two 16-bit scans of a bump (different seeds) as an observations section."""
    curve = bump()
    files = []
    for k in range(n):
        img, _, origin = _scan(curve, seed=10 + k, looks=4.0)
        path = tmp_path / f"scan_{k}.tif"
        io.imsave(path, _to_bits(img, 16), check_contrast=False)
        files.append({"path": str(path), "label": f"scan_{k}", "load": None, "units": "mm",
                      "pixel_size": S, "origin": list(origin), "floor": "auto"})
    return {"source": "files", "files": files, "domain": [[0.0, 2.0], [0.0, 1.0]]}


def test_the_segmentation_uncertainty_is_stored_per_snapshot(tmp_path):
    from bayescalib.io.observation_store import read_observations
    from bayescalib.stages.observe import observe

    section = _files_section(tmp_path)
    observe(section, tmp_path / "observations.h5")
    obs = read_observations(tmp_path / "observations.h5")
    assert obs.segmentation is not None and len(obs.segmentation) == 2
    for rec in obs.segmentation:
        assert rec["kind"] == "scan" and rec["bit_depth"] == 16
        assert rec["floor"]["method"] == "image bottom" and rec["floor_mm"] is None
        # 4-look speckle: a few tenths of a pixel
        assert 0.25 * S < rec["sigma_mm"] < 0.6 * S
    expected = np.sqrt(np.mean([r["sigma_mm"] ** 2 for r in obs.segmentation]))
    assert obs.segmentation_sigma() == pytest.approx(expected)
    # masks (and coordinates) carry none: the diagnosis behaves as before
    from bayescalib.io.observations import write_mask_png

    mask, _ = read_mask(section["files"][0]["path"])
    write_mask_png(tmp_path / "mask.png", mask, pixel_size=S, origin=section["files"][0]["origin"])
    observe({**section, "files": [{**section["files"][0], "path": str(tmp_path / "mask.png")}]},
            tmp_path / "masks.h5")
    masks = read_observations(tmp_path / "masks.h5")
    assert masks.segmentation[0]["kind"] == "mask" and masks.segmentation_sigma() is None


def test_the_diagnosis_takes_the_segmentation_uncertainty_as_a_lower_bound():
    """The data-based noise estimate is kept when it is larger; the segmentation's
    uncertainty is used, and the source says so, when the estimate falls below it;
    a given sigma stays given, with the segmentation value reported beside it."""
    from bayescalib.diagnosis.residuals import predictive_check

    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 1.0, 200)
    obs = [Interface.polyline(np.column_stack([x, 0.002 * rng.standard_normal(x.size)]))]
    draws = [[Interface.polyline(np.column_stack([x, np.full_like(x, 1e-4 * k)]))]
             for k in (-1, 1)]
    kw = {"rng": np.random.default_rng(1), "ell": 0.0}
    base = predictive_check(obs, draws, **kw)
    assert base.sigma_source == "estimated" and "sigma_segmentation_mm" not in base.to_json()
    low = predictive_check(obs, draws, segmentation_sigma=0.1 * base.sigma, **kw)
    assert low.sigma == pytest.approx(base.sigma) and low.sigma_source == "estimated"
    assert low.to_json()["sigma_segmentation_mm"] == pytest.approx(0.1 * base.sigma)
    high = predictive_check(obs, draws, segmentation_sigma=3 * base.sigma, **kw)
    assert high.sigma == pytest.approx(3 * base.sigma)
    assert high.sigma_source == "segmentation (lower bound)"
    assert high.to_json()["sigma_data_mm"] == pytest.approx(base.sigma)
    given = predictive_check(obs, draws, sigma=0.001, segmentation_sigma=0.01, **kw)
    assert given.sigma == 0.001 and given.sigma_source == "given"
    assert given.to_json()["sigma_segmentation_mm"] == 0.01


def test_the_segmentation_figure_is_drawn_through_the_job_stage(tmp_path):
    from bayescalib.execution.jobserver import run_job
    from bayescalib.stages.observe import observe

    section = _files_section(tmp_path)
    observe(section, tmp_path / "observations.h5")
    plots = {"formats": ["png"], "dpi": 50}
    run_job({"stage": "fig_segmentation", "log": str(tmp_path / "fig.log"),
             "args": {"obs_path": str(tmp_path / "observations.h5"), "observations": section,
                      "plots": plots, "stem": str(tmp_path / "segmentation")}})
    assert (tmp_path / "segmentation.png").stat().st_size > 5000


@pytest.mark.workflow
def test_a_files_study_with_an_image_plans_the_segmentation_figure(tmp_path):
    """Dry run: the figure rule is planned, is in rule all (via the figure map of
    summary.json) only when an observation file is an image."""
    from _workflow_helpers import setup_study, smk

    section = _files_section(tmp_path, n=1)
    study = {
        "study": "scans",
        "forward_model": {"type": "python", "time_limit_s": 60,
                          "python": {"function": "bayescalib.models.analytic:interface"}},
        "parameters": [
            {"name": "E", "unit": "Pa", "target": "E",
             "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}, "bounds": [100.0, 800.0]},
            {"name": "nu", "unit": "-", "target": "nu",
             "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}, "bounds": [-0.8, 0.45]}],
        "measures": ["cpp"],
        "likelihood": {"sigma_n": 0.002},
        "design": {"strategy": "fixed", "n_train": 8, "seed": 1},
        "plots": {"formats": ["png"], "n_interface_samples": 0, "fields": False},
        "observations": section,
    }
    setup_study(tmp_path, study)
    out = smk(tmp_path, "-n").stdout
    assert "rule fig_segmentation:" in out and "results/scans/figures/segmentation.png" in out
    csv = tmp_path / "c.csv"
    csv.write_text("x,y\n0.2,0.0\n0.6,0.12\n1.0,0.0\n")
    setup_study(tmp_path, {**study, "observations": {**section, "files": [{"path": str(csv)}]}})
    assert "fig_segmentation" not in smk(tmp_path, "-n").stdout
